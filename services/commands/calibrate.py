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
so an optimistic figure), and each sensor's error: what each model's sensors read
along the run's tracked path against what the robot read (median counts).
``--out FILE`` writes the twin (JSON: values, errors, runs, who fitted and when);
``--save --user U`` has the registry keep it as the robot's newest version (``wart
twin``; the owner of the arena named with ``--arena``, or a lab admin).
docs/CALIBRATION.md.

    wart calibrate k1 --recordings dance.mcap other-run.mcap --out k1-twin.json
    wart calibrate k1 --recordings dance.mcap --save --user carol --arena real
"""

from __future__ import annotations

import argparse
import getpass
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from common import cli, keys
from common.lab_errors import LabError
from common.recording import RecordingError, read_recording
from common.twin import gap
from common.twin.fit import TwinError, calibrate, run_data
from common.twin.motion import Drive
from common.twin.twinfile import TwinFileError, parse_twin
from common.zconfig import NetworkOptions
from services.commands.arena import lab_login
from services.commands.twin import add_login_arguments, save_twin
from services.lab.labfile import LabFileError


def main(argv: Sequence[str] | None = None, prog: str = "wart calibrate") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("robot", help="the real robot's name in its arena (k1)")
    p.add_argument(
        "--recordings", type=Path, nargs="+", required=True, metavar="FILE",
        help="recorded runs of the robot (.mcap), with the arena camera's poses of it",
    )  # fmt: skip
    p.add_argument("--out", type=Path, metavar="FILE", help="write the twin there (JSON)")
    p.add_argument(
        "--save", action="store_true",
        help="have the registry keep the twin as the robot's newest version (--user)",
    )  # fmt: skip
    p.add_argument("--arena", help="with --save: the arena you own (lab admins: none)")
    add_login_arguments(p, required=False)
    args, options = cli.parse_networked(p, argv)
    if args.save and args.user is None:
        p.error("--save needs --user (an arena's owner or a lab admin: wart twin)")
    if args.arena is not None:
        try:
            keys.check_ident("--arena", args.arena)
        except ValueError as exc:
            p.error(str(exc))
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
    print(f"{gap.heading()}; of several runs, the worst run's:")
    for name, drive in (("datasheet", Drive()), ("twin", twin.fitted_drive())):
        print(f"  {gap.gap(name, drive, runs).line()}")
    text = twin.to_json(getpass.getuser(), time.time()) + "\n"
    fitted = parse_twin(text, f"{args.robot}'s twin")
    for run in runs:
        print("\n".join(gap.sensor_lines(run, fitted, run.name)))
    print("  (on the runs it was fitted to: record another run to check it on new data)")
    if args.out is not None:
        try:
            args.out.write_text(text)
        except OSError as exc:
            return cli.fail(f"cannot write {args.out}: {exc.strerror or exc}", 1)
        print(f"wrote {args.out}")
    return _save(args, options, text) if args.save else 0


def _save(args: argparse.Namespace, options: NetworkOptions, text: str) -> int:
    try:
        kept = parse_twin(text, f"{args.robot}'s twin")
        with lab_login(args, options) as client:
            return save_twin(client, kept, args.arena)
    except (TwinFileError, LabError, LabFileError, ValueError, OSError) as exc:
        return cli.fail(f"not kept: {exc}", 1)


if __name__ == "__main__":
    sys.exit(main())
