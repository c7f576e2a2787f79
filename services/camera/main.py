"""``wart camera``: one camera over a world's arena (what the service does: service.py).

wart camera --world real1 --source /dev/video0 --calibration arena.json
wart camera calibrate --world real1 --source /dev/video0 --out arena.json
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import zenoh

from common import cli, keys
from common.service import close_session, open_session, run_service
from common.tracking.calibration import ArenaCalibration, CalibrationError, calibrate
from common.tracking.markers import default_layout
from services.camera import service
from services.camera.service import CameraOptions, CameraService, world_snapshot
from services.camera.sources import SourceError, check_spec, open_source

SOURCE_HELP = (
    "what to capture: a V4L2 device (/dev/video0, or its index 0), a video file, a network "
    "stream (rtsp://..., http://...), or synthetic:FILE (a camera rendered from the Khepera "
    "emulator's truth file, for labs without hardware)"
)


def _source_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", required=True, help="the world whose arena the camera sees")
    p.add_argument("--source", required=True, help=SOURCE_HELP)
    p.add_argument(
        "--camera-height",
        type=float,
        default=1500.0,
        metavar="MM",
        help="the camera's height above the floor (default 1500), for a camera looking "
        "straight down without known intrinsics",
    )


def _positive(kind: Callable[[str], float], low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a number of ``kind`` from ``low`` to ``high``, said in words if not."""

    def check(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be {low:g} to {high:g}; got {text}")
        return value

    return check


def main(argv: Sequence[str] | None = None, prog: str = "wart camera") -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["calibrate"]:
        return calibrate_main(argv[1:], f"{prog} calibrate")
    p = cli.parser(prog, (service.__doc__ or "") + "\n\nAlso: wart camera calibrate --help")
    _source_arguments(p)
    p.add_argument("--name", help="this camera's name (default: WORLD-cam)")
    p.add_argument(
        "--fps",
        type=_positive(float, 1, 30),
        default=10.0,
        help="frames a second (1 to 30, default 10)",
    )
    p.add_argument(
        "--max-width",
        type=_positive(int, 160, 1920),
        default=640,
        help="published frames at most this wide (default 640)",
    )
    p.add_argument(
        "--max-height",
        type=_positive(int, 120, 1080),
        default=480,
        help="and this high (default 480)",
    )
    p.add_argument(
        "--quality",
        type=_positive(int, 20, 95),
        default=70,
        help="JPEG quality 20 to 95 (default 70)",
    )
    p.add_argument(
        "--calibration",
        type=Path,
        metavar="FILE",
        help="the arena's calibration (wart camera calibrate)",
    )
    p.add_argument(
        "--auto-calibrate",
        action="store_true",
        help="without a calibration file, calibrate from the reference markers once they are in "
        "view (and save it to --calibration FILE when given)",
    )
    p.add_argument("--loop", action="store_true", help="a video file starts again at its end")
    args, options = cli.parse(p, argv)
    assert options is not None
    try:
        check_spec(args.source)
        keys.check_ident("world", args.world)
        name = args.name or f"{args.world}-cam"
        keys.check_ident("camera", name)
    except ValueError as exc:
        p.error(str(exc))
    if args.calibration is not None and args.calibration.exists():
        try:
            ArenaCalibration.load(args.calibration)
        except CalibrationError as exc:
            return cli.fail(str(exc))
    camera_options = CameraOptions(
        fps=args.fps,
        max_width=args.max_width,
        max_height=args.max_height,
        jpeg_quality=args.quality,
        calibration=args.calibration,
        auto_calibrate=args.auto_calibrate,
        camera_height_mm=args.camera_height,
    )

    def build(session: zenoh.Session) -> CameraService:
        source = open_source(args.source, loop=args.loop)
        return CameraService(
            session, options.realm, name, world=args.world, source=source, options=camera_options
        )

    return run_service(f"camera {name}", options, build)


def calibrate_main(argv: Sequence[str], prog: str) -> int:
    p = cli.parser(
        prog,
        "Calibrate a camera over its arena: find the four reference markers in one frame and "
        "save the floor's homography.\nThe arena's size comes from the world's snapshot "
        "(--world, on the lab's network), or from --arena WIDTHxHEIGHT (mm) offline.",
    )
    _source_arguments(p)
    p.add_argument(
        "--out", type=Path, required=True, metavar="FILE", help="where to save the calibration"
    )
    p.add_argument(
        "--arena", metavar="WxH", help="the arena's size in mm, without asking the world"
    )
    args, options = cli.parse(p, argv)
    assert options is not None
    try:
        check_spec(args.source)
    except ValueError as exc:
        p.error(str(exc))
    if args.arena:
        try:
            width, height = (float(v) for v in args.arena.lower().split("x"))
        except ValueError:
            p.error(f"--arena must be WIDTHxHEIGHT in mm, e.g. 1000x1000; got {args.arena!r}")
    else:
        session = open_session(options, wait=10.0)
        try:
            snap = world_snapshot(session, options.realm, args.world)
        finally:
            close_session(session)
        if snap is None:
            return cli.fail(f"world {args.world} did not answer; is it running? (or give --arena)")
        width, height = float(snap.width), float(snap.height)
    source = open_source(args.source)
    try:
        source.open()
        frame = source.read()
    except SourceError as exc:
        return cli.fail(str(exc))
    finally:
        source.close()
    try:
        cal = calibrate(
            frame,
            default_layout(width, height, []),
            camera_height_mm=args.camera_height,
            camera_matrix=source.camera_matrix,
            dist_coeffs=source.dist_coeffs,
        )
    except CalibrationError as exc:
        cv2.imwrite(str(args.out.with_suffix(".seen.jpg")), frame)
        return cli.fail(f"{exc}\n(the frame it saw: {args.out.with_suffix('.seen.jpg')})")
    cal.save(args.out)
    print(
        f"calibrated {frame.shape[1]}x{frame.shape[0]} from the reference markers: "
        f"{cal.rms_mm:.1f} mm rms; saved to {args.out}"
    )
    return 0
