"""``wart camera``: one camera over a world's arena (what the service does: service.py).

wart camera --world real1 --source /dev/video0 --calibration arena.json
wart camera calibrate --intrinsics --source board.mp4 --out arena.json   (the lens)
wart camera calibrate --world real1 --source /dev/video0 --out arena.json (the arena)
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli, keys
from common.service import run_service
from common.tracking.calibration import (
    ArenaCalibration,
    CalibrationError,
    floor_calibrated,
    read_intrinsics,
)
from services.camera import service
from services.camera.arguments import positive, source_arguments
from services.camera.calibrate import calibrate_main
from services.camera.service import CameraOptions, CameraService
from services.camera.sources import check_spec, open_source


def main(argv: Sequence[str] | None = None, prog: str = "wart camera") -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["calibrate"]:
        return calibrate_main(argv[1:], f"{prog} calibrate")
    p = cli.parser(prog, (service.__doc__ or "") + "\n\nAlso: wart camera calibrate --help")
    source_arguments(p)
    p.add_argument("--name", help="this camera's name (default: WORLD-cam)")
    p.add_argument(
        "--fps",
        type=positive(float, 1, 30),
        help="frames a second, 1 to 30 (default: 10 from a live camera; a video file at its "
        "own rate, or sampled at this rate from its own timeline)",
    )
    p.add_argument(
        "--max-width",
        type=positive(int, 160, 1920),
        default=640,
        help="published frames at most this wide (default 640)",
    )
    p.add_argument(
        "--max-height",
        type=positive(int, 120, 1080),
        default=480,
        help="and this high (default 480)",
    )
    p.add_argument(
        "--quality",
        type=positive(int, 20, 95),
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
    p.add_argument(
        "--layout-check",
        type=positive(float, 1, 3600),
        default=30.0,
        metavar="SECONDS",
        help="read the world's robots again this often besides when it says they changed, "
        "1 to 3600 (default 30)",
    )
    p.add_argument(
        "--loop",
        action="store_true",
        help="a video file starts again at its end (without: the camera goes offline there "
        "and stays offline)",
    )
    args, options = cli.parse_networked(p, argv)
    try:
        check_spec(args.source)
        keys.check_ident("world", args.world)
        name = args.name or f"{args.world}-cam"
        keys.check_ident("camera", name)
    except ValueError as exc:
        p.error(str(exc))
    if args.calibration is not None and args.calibration.exists():
        try:
            if floor_calibrated(args.calibration):
                ArenaCalibration.load(args.calibration)
            elif not args.auto_calibrate:
                return cli.fail(
                    f"{args.calibration} holds the lens only: add --auto-calibrate to calibrate "
                    "the arena's floor with it (or run `wart camera calibrate --world ...`)"
                )
            read_intrinsics(args.calibration)
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
        reference_grid=args.reference_grid,
        layout_check_s=args.layout_check,
    )

    def build(session: zenoh.Session) -> CameraService:
        source = open_source(
            args.source,
            loop=args.loop,
            sample_fps=args.fps,
            grid=args.reference_grid,
            over=args.synthetic_over,
        )
        return CameraService(
            session, options.realm, name, world=args.world, source=source, options=camera_options
        )

    return run_service(f"camera {name}", options, build)
