"""``wart camera calibrate``: the camera's lens from a ChArUco board, then the arena's floor.

A lab calibrates in two steps, both saved in one file:

wart camera calibrate --intrinsics --source board.mp4 --out arena.json
wart camera calibrate --world real1 --source /dev/video0 --out arena.json

The first films or photographs a ChArUco board (a video, or a folder of
photos) and saves the lens (OpenCV's pinhole model, its reprojection error and
each parameter's standard deviation); the second finds the arena's reference
markers and, with the lens from the same file, solves the camera's pose.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from common import cli
from common.service import close_session, open_session
from common.tracking.calibration import (
    CalibrationError,
    calibrate,
    read_intrinsics,
    save_intrinsics,
)
from common.tracking.intrinsics import BoardSpec, IntrinsicsCollector, IntrinsicsError
from common.tracking.markers import default_layout
from services.camera.arguments import DEFAULT_HEIGHT_MM, positive, source_arguments
from services.camera.service import world_snapshot
from services.camera.sources import SourceError, check_spec, open_source

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def calibrate_main(argv: Sequence[str], prog: str) -> int:
    if "--intrinsics" in argv:
        return intrinsics_main([a for a in argv if a != "--intrinsics"], f"{prog} --intrinsics")
    p = cli.parser(
        prog,
        "Calibrate a camera over its arena: find the reference markers it sees in one frame "
        "(at least 3; one of several cameras over a big arena: --reference-grid) and "
        "save the floor's homography.\nThe arena's size comes from the world's snapshot "
        "(--world, on the lab's network), or from --arena WIDTHxHEIGHT (mm) offline.\n"
        "When --out already holds the camera's intrinsics (--intrinsics), they are used and "
        "kept.\n\nAlso: wart camera calibrate --intrinsics --help",
    )
    source_arguments(p)
    p.add_argument(
        "--out", type=Path, required=True, metavar="FILE", help="where to save the calibration"
    )
    p.add_argument(
        "--arena", metavar="WxH", help="the arena's size in mm, without asking the world"
    )
    args, options = cli.parse_networked(p, argv)
    try:
        check_spec(args.source)
    except ValueError as exc:
        p.error(str(exc))
    lens = None
    if args.out.exists():
        try:
            lens = read_intrinsics(args.out)
        except CalibrationError as exc:
            return cli.fail(str(exc))
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
    source = open_source(args.source, grid=args.reference_grid, over=args.synthetic_over)
    try:
        source.open()
        frame = source.read()
    except SourceError as exc:
        return cli.fail(str(exc))
    finally:
        source.close()
    size = (frame.shape[1], frame.shape[0])
    if lens is not None and lens.image_size != size:
        return cli.fail(
            f"{args.out} holds intrinsics for {lens.image_size[0]}x{lens.image_size[1]} but the "
            f"camera gives {size[0]}x{size[1]}: calibrate the intrinsics again at this size"
        )
    try:
        cal = calibrate(
            frame,
            default_layout(width, height, [], grid=args.reference_grid),
            camera_height_mm=args.camera_height
            if args.camera_height is not None
            or lens is not None
            or source.camera_matrix is not None
            else DEFAULT_HEIGHT_MM,
            camera_matrix=source.camera_matrix if lens is None else lens.camera_matrix,
            dist_coeffs=source.dist_coeffs if lens is None else lens.dist_coeffs,
            lens=lens,
        )
    except CalibrationError as exc:
        cv2.imwrite(str(args.out.with_suffix(".seen.jpg")), frame)
        return cli.fail(f"{exc}\n(the frame it saw: {args.out.with_suffix('.seen.jpg')})")
    cal.save(args.out)
    print(
        f"calibrated {frame.shape[1]}x{frame.shape[0]} from the reference markers: "
        f"{cal.rms_mm:.1f} mm rms; saved to {args.out}"
    )
    print(cal.report())
    for warning in cal.warnings():
        print(f"warning: {warning}")
    return 0


def _board(text: str) -> tuple[int, int]:
    try:
        columns, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be COLUMNSxROWS of squares, e.g. 9x6; got {text!r}"
        ) from None
    return columns, rows


def frames_of(path: Path) -> Iterator[tuple[str, np.ndarray, bool]]:
    """(name, frame, follows the previous one) for each image of a folder (by name) or
    each frame of a video file."""
    if path.is_dir():
        for image in sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
            frame = cv2.imread(str(image), cv2.IMREAD_COLOR)
            if frame is not None:
                yield image.name, frame, False
        return
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        index = 0
        while True:
            ok, frame = capture.read()
            if not ok or frame is None:
                return
            yield f"frame {index}", frame, True
            index += 1
    finally:
        capture.release()


def intrinsics_main(argv: Sequence[str], prog: str) -> int:
    p = cli.parser(
        prog,
        "Calibrate the camera's lens from a ChArUco board, as OpenCV and ROS's "
        "camera_calibration do: show the board at many places, distances and angles (a video, "
        "or a folder of photos). Each view kept prints the coverage bars (x, y, size, skew); "
        "blurred, moving and near-duplicate views are refused. Saved in --out with the "
        "reprojection error and each parameter's standard deviation; calibrate the arena "
        "next with the same --out.",
        network=False,
    )
    p.add_argument("--source", type=Path, required=True, help="a video file, or a folder of photos")
    p.add_argument(
        "--out", type=Path, required=True, metavar="FILE", help="where to save the intrinsics"
    )
    p.add_argument(
        "--board",
        type=_board,
        default=(9, 6),
        metavar="CxR",
        help="the board's squares across and down (default 9x6)",
    )
    p.add_argument(
        "--square",
        type=positive(float, 1, 1000),
        default=50.0,
        metavar="MM",
        help="a square's side as printed (default 50)",
    )
    p.add_argument(
        "--marker",
        type=positive(float, 1, 1000),
        default=37.0,
        metavar="MM",
        help="a marker's side as printed (default 37)",
    )
    p.add_argument(
        "--dictionary", default="5X5_100", help="the board's ArUco dictionary (default 5X5_100)"
    )
    args, _ = cli.parse(p, argv)
    if not args.source.exists():
        return cli.fail(f"no video file or folder at {args.source}")
    try:
        board = BoardSpec(args.board[0], args.board[1], args.square, args.marker, args.dictionary)
    except IntrinsicsError as exc:
        p.error(str(exc))
    collector = IntrinsicsCollector(board)
    offered = 0
    for name, frame, consecutive in frames_of(args.source):
        offered += 1
        verdict = collector.offer(frame, consecutive=consecutive)
        if verdict.kept:
            print(f"{name}: kept; {collector.progress()}", flush=True)
    refused = ", ".join(f"{n} {why}" for why, n in collector.refused.most_common()) or "none"
    print(f"{offered} frames, {len(collector.views)} views kept; refused: {refused}")
    if not collector.enough:
        short = ", ".join(f"{k} {100 * v:.0f} %" for k, v in collector.coverage().items() if v < 1)
        print(f"coverage not full ({short or 'too few views'}): more angles would help")
    try:
        lens = collector.calibrate()
    except IntrinsicsError as exc:
        return cli.fail(str(exc))
    save_intrinsics(args.out, lens)
    print(f"intrinsics: {lens.summary()}; saved to {args.out}")
    print(
        f"next: wart camera calibrate --world WORLD --source SOURCE --out {args.out} "
        "(the arena, with this lens)"
    )
    return 0
