"""``wart report FILE``: the summary of a recorded run (an MCAP file from ``wart record get``).

Prints who ran what on which robot, how the slot ended, distance travelled,
time moving, collisions (the robot's disc or tongs touching the arena's wall, an
obstacle or another robot, from the recorded poses), objects gripped and
delivered to a nest, and the errors the controller raised with their line
numbers. ``--json`` prints the same as JSON; ``--plots DIR`` also draws the
trajectory over the map and the IR and wheel speeds over time (PNG, needs
matplotlib). A damaged or cut-short file is reported as such: what it holds is
summarised, with a warning.

Sim beside real: ``wart report SIM.mcap --against REAL.mcap`` compares two runs
of the same controller (say a simulated robot and the real one, from the same
start pose): final pose error, path length ratio, collisions of each on one
map, and per-sensor mean differences of IR and ambient over time-aligned
samples (REAL minus SIM). With ``--plots DIR``: both trajectories on one map
and every IR and ambient sensor of both runs overlaid.

The gap, for a real run (REAL, or FILE alone) watched by the arena camera: with
``--twin FILE`` (a twin file, ``wart calibrate --out``) or ``--db DB`` (the robot's
twin in force in the lab's database, ``wart twin``), the datasheet model and the
twin, each run open-loop on the run's recorded commands from every camera pose,
against where the camera saw the robot 1, 5 and 10 s later (median mm), side by
side; then each IR sensor's error: what each model's sensors read along the run's
tracked path, in its arena rebuilt from the recording, against what the robot read
(median counts), and the ambient sensors' (needs the lab's packages: scipy and the
simulator).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import msgspec

from common import cli
from common.recording import Recording, RecordingError, Summary, plots, read_recording, summarize
from common.recording.compare import Comparison, compare
from common.recording.report import describe, describe_comparison


def _write_plots(paths: list[Path] | None) -> None:
    for path in paths or []:
        print(f"wrote {path}")


def _gap(real: Recording, name: str, twin_file: Path | None, db: Path | None) -> list[str]:
    """The datasheet model's and the twin's open-loop gap on the real run, as lines."""
    # The lab's packages (scipy, the simulator; the database's for --db), imported here:
    # a client install (pip install wart-lab) reports runs without them, and no gap.
    from common.twin.gap import side_by_side
    from common.twin.twinfile import parse_twin
    from services.lab.twins_db import TwinStore

    if twin_file is not None:
        try:
            return side_by_side(real, name, parse_twin(twin_file.read_bytes(), str(twin_file)))
        except OSError as exc:
            raise ValueError(f"cannot read {twin_file}: {exc.strerror or exc}") from None
    assert db is not None
    # The twin in force in the run's arena (its agent context): the arena's own, else one
    # kept for no arena.
    agent, arena = (real.info.agent, real.info.ctx) if real.info is not None else ("", "")
    store = TwinStore.open(db)
    try:
        stored = store.current(arena, agent)
    finally:
        store.close()
    if stored is None:
        robot = f"{agent} in {arena}" if agent and arena else (agent or "its robot")
        raise ValueError(f"no twin of {robot} is kept in {db} (wart twin)")
    return side_by_side(real, name, stored.twin)


def main(argv: Sequence[str] | None = None, prog: str = "wart report") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("file", type=Path, help="a recording (.mcap); with --against, run A (sim)")
    p.add_argument(
        "--against",
        type=Path,
        metavar="FILE",
        help="compare with this recording, run B (real): sim beside real",
    )
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--plots", type=Path, metavar="DIR", help="also write plots (PNG) there")
    twin = p.add_mutually_exclusive_group()
    twin.add_argument(
        "--twin", type=Path, metavar="FILE",
        help="the real robot's twin file: its gap beside the datasheet's",
    )  # fmt: skip
    twin.add_argument(
        "--db", type=Path, metavar="DB",
        help="the lab's database: the real robot's twin in force there",
    )  # fmt: skip
    args, _ = cli.parse(p, argv)
    if args.plots is not None and not plots.available():
        # Said before any work: the numbers alone are one flag away.
        return cli.fail("--plots needs matplotlib (pip install matplotlib; or drop --plots)", 1)
    try:
        recording = read_recording(args.file)
        other = read_recording(args.against) if args.against is not None else None
        result: Summary | Comparison
        result = summarize(recording) if other is None else compare(recording, other)
    except RecordingError as exc:
        return cli.fail(str(exc), 1)
    gap_lines: list[str] = []
    if args.twin is not None or args.db is not None:
        real, real_path = (recording, args.file) if other is None else (other, args.against)
        try:
            gap_lines = _gap(real, real_path.stem, args.twin, args.db)
        except ValueError as exc:  # TwinError, TwinFileError, DbError: said in words
            return cli.fail(str(exc), 1)
    if args.json:
        text = msgspec.json.encode(result).decode()
        if gap_lines:
            text = f'{{"report": {text}, "gap": {msgspec.json.encode(gap_lines).decode()}}}'
        print(msgspec.json.format(text))
    elif isinstance(result, Comparison):
        print("\n".join([*describe_comparison(result), *gap_lines]))
    else:
        print("\n".join([*describe(result), *gap_lines]))
    if args.plots is not None:
        try:
            if other is None:
                _write_plots(plots.write_plots(recording, args.plots, args.file.stem))
            else:
                assert isinstance(result, Comparison)
                stem = f"{args.file.stem}-vs-{args.against.stem}"
                _write_plots(
                    plots.write_comparison_plots(recording, other, result, args.plots, stem)
                )
        except OSError as exc:
            return cli.fail(f"cannot write the plots: {exc}", 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
