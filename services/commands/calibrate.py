"""``wart calibrate ROBOT --recordings RUN.mcap ...``: a real robot's twin, fitted from its runs.

Reads recordings of ROBOT's runs on a real arena watched by the arena camera
(``wart record get``; examples/calibration_dance.py is a run that shows every
parameter) and fits what this robot differs from its datasheet by: each wheel's
scale (slip), the wheel base, the command-to-motion latency, each IR sensor's gain
and noise. Each value is printed with its standard error and the runs that
constrained it; one the runs cannot constrain is refused with the reason and kept
at the datasheet's. Then the gap: the datasheet model and the fitted twin, each
run open-loop on the recorded commands from every camera pose, against where the
camera saw the robot 1, 5 and 10 s later (median mm; the same runs as the fit,
so an optimistic figure). ``--out FILE`` writes the twin (JSON: values, errors,
runs, who fitted and when). docs/CALIBRATION.md.

    wart calibrate k1 --recordings dance.mcap other-run.mcap --out k1-twin.json
"""

from __future__ import annotations

import getpass
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from common import cli
from common.recording import RecordingError, read_recording
from common.twin.fit import TwinError, calibrate, open_loop_error, run_data
from common.twin.motion import Drive

HORIZONS_S = (1.0, 5.0, 10.0)


def main(argv: Sequence[str] | None = None, prog: str = "wart calibrate") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("robot", help="the real robot's name in its arena (k1)")
    p.add_argument(
        "--recordings", type=Path, nargs="+", required=True, metavar="FILE",
        help="recorded runs of the robot (.mcap), with the arena camera's poses of it",
    )  # fmt: skip
    p.add_argument("--out", type=Path, metavar="FILE", help="write the twin there (JSON)")
    args, _ = cli.parse(p, argv)
    loaded = []
    for path in args.recordings:
        try:
            loaded.append((path.stem, read_recording(path)))
        except RecordingError as exc:
            return cli.fail(str(exc), 1)
    try:
        twin = calibrate(args.robot, loaded)
    except TwinError as exc:
        return cli.fail(str(exc), 1)
    runs = [run_data(rec, name) for name, rec in loaded if name in twin.runs]
    seconds = sum(r.poses[-1, 0] - r.poses[0, 0] for r in runs)
    print(f"{args.robot}'s twin from {len(runs)} run(s), {seconds:.0f} s with camera poses:")
    for line in twin.lines():
        print(f"  {line}")
    fitted = twin.fitted_drive()
    after = " / ".join(f"{h:g}" for h in HORIZONS_S)
    print(f"open-loop error after {after} s (median mm; of several runs, the worst run's):")
    for name, drive in (("datasheet", Drive()), ("twin", fitted)):
        figures = []
        for horizon in HORIZONS_S:
            errors = [open_loop_error(drive, r, horizon) for r in runs]
            known = [e for e in errors if e == e]  # NaN: a run shorter than the horizon
            figures.append(f"{max(known):.1f}" if known else "-")
        print(f"  {name}: {' / '.join(figures)}")
    print("  (on the runs it was fitted to: record another run to check it on new data)")
    if args.out is not None:
        try:
            args.out.write_text(twin.to_json(getpass.getuser(), time.time()) + "\n")
        except OSError as exc:
            return cli.fail(f"cannot write {args.out}: {exc.strerror or exc}", 1)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
