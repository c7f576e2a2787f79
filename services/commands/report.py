"""``wart report FILE``: the summary of a recorded run (an MCAP file from ``wart record get``).

Prints who ran what on which robot, how the slot ended, distance travelled,
time moving, collisions (the robot within its radius of a wall or obstacle,
from the recorded poses), objects gripped and delivered to a nest, and the
errors the controller raised with their line numbers. ``--json`` prints the
same as JSON; ``--plots DIR`` also draws the trajectory over the map and the
IR and wheel speeds over time (PNG, needs matplotlib). A damaged or cut-short
file is reported as such: what it holds is summarised, with a warning.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

import msgspec

from common import cli
from common.recording import RecordingError, Summary, plots, read_recording, summarize


def describe(summary: Summary) -> list[str]:
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(summary.start))
    file = f" ({summary.filename})" if summary.filename else ""
    lines = [
        f"run {summary.request_id}: {summary.user} on {summary.agent} in {summary.ctx} "
        f"(world {summary.world}), {summary.mode}{file}, {when}",
        f"ended:       {summary.status}: {summary.reason}",
        f"duration:    {summary.duration_s:.1f} s of simulated time",
        f"distance:    {summary.distance_mm / 1000:.3f} m",
        f"moving:      {summary.moving_s:.1f} s",
        f"collisions:  {summary.collisions} ({summary.contact_s:.1f} s in contact)",
        f"objects:     {summary.gripped} gripped, {summary.delivered} delivered to a nest",
        f"recorded:    {summary.frames} frames, {summary.samples} sensor samples, "
        f"{summary.commands} commands, {summary.output_lines} output lines",
    ]
    if summary.errors:
        lines.append(f"errors:      {len(summary.errors)}")
        for e in summary.errors:
            where = f"line {e.line}" if e.line is not None else "line unknown"
            lines.append(f"  {where}: {e.kind}: {e.message}")
    else:
        lines.append("errors:      none")
    if summary.truncated:
        lines.append(f"warning:     {summary.truncated}")
    return lines


def main(argv: Sequence[str] | None = None, prog: str = "wart report") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("file", type=Path, help="a recording (.mcap)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--plots", type=Path, metavar="DIR", help="also write plots (PNG) there")
    args, _ = cli.parse(p, argv)
    try:
        recording = read_recording(args.file)
    except RecordingError as exc:
        return cli.fail(str(exc), 1)
    summary = summarize(recording)
    if args.json:
        print(msgspec.json.format(msgspec.json.encode(summary).decode()))
    else:
        print("\n".join(describe(summary)))
    if args.plots is not None:
        if not plots.available():
            return cli.fail("--plots needs matplotlib (pip install matplotlib)", 1)
        try:
            for path in plots.write_plots(recording, args.plots, args.file.stem):
                print(f"wrote {path}")
        except OSError as exc:
            return cli.fail(f"cannot write the plots: {exc}", 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
