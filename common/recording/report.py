"""A recorded run's summary, and two runs compared, as the lines ``wart report`` prints.

The page's recordings panel shows the same lines (viewers/web/recordings_panel.py).
"""

from __future__ import annotations

import math
import time

from common.recording.compare import Comparison
from common.recording.summary import Summary


def _with(collided: dict[str, int]) -> str:
    """ ": 2 with a robot, 1 with the wall": what the collisions were with."""
    names = {"wall": "the wall", "obstacle": "an obstacle", "robot": "a robot"}
    return "".join(
        (": " if i == 0 else ", ") + f"{n} with {names.get(k, k)}"
        for i, (k, n) in enumerate(collided.items())
    )


def _collisions(summary: Summary) -> str:
    counted = (
        f"{summary.collisions}{_with(summary.collided_with)} ({summary.contact_s:.1f} s in contact)"
    )
    if summary.world_kind != "real":
        return f"collisions:  {counted}"
    # A real robot has no contact sensor: the count is the tracked poses against the map.
    if summary.frames == 0:
        return "collisions:  not measured (real robots, and no tracked poses recorded)"
    return f"collisions:  {counted}, estimated from the tracked poses (not measured)"


def describe(summary: Summary) -> list[str]:
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(summary.start))
    file = f" ({summary.filename})" if summary.filename else ""
    lines = [
        f"run {summary.request_id}: {summary.user} on {summary.agent} in {summary.ctx} "
        f"(world {summary.world}), {summary.mode}{file}, {when}",
        f"ended:       {summary.status}: {summary.reason}",
        f"duration:    {summary.duration_s:.1f} s of "
        + ("real time" if summary.world_kind == "real" else "simulated time"),
        f"distance:    {summary.distance_mm / 1000:.3f} m",
        f"moving:      {summary.moving_s:.1f} s",
        _collisions(summary),
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


def _pose(p: tuple[float, float, float]) -> str:
    return f"({p[0]:.0f}, {p[1]:.0f}) mm, {math.degrees(p[2]):.0f} deg"


def _per_sensor(values: list[float], signed: bool = True) -> str:
    form = "{:+.1f}" if signed else "{:.1f}"
    return "  ".join(form.format(v) for v in values) if values else "n/a"


def describe_comparison(cmp: Comparison) -> list[str]:
    a, b = cmp.a, cmp.b
    ratio = "n/a" if cmp.path_length_ratio is None else f"{cmp.path_length_ratio:.3f}"
    heading = math.degrees(cmp.final_heading_error_rad)
    lines = [
        f"A = {a.label}: run {a.request_id} on {a.agent} in {a.ctx} (world {a.world}), "
        f"{a.status}, {a.duration_s:.1f} s, {a.frames} frames, {a.samples} samples",
        f"B = {b.label}: run {b.request_id} on {b.agent} in {b.ctx} (world {b.world}), "
        f"{b.status}, {b.duration_s:.1f} s, {b.frames} frames, {b.samples} samples",
        "poses from:         "
        + "; ".join(
            f"{n} {'the arena camera (tracked)' if s.poses_from == 'camera' else 'its frames'}"
            for n, s in (("A", a), ("B", b))
        ),
        f"start pose:         A {_pose(a.start_pose)}; B {_pose(b.start_pose)} "
        f"({cmp.start_offset_mm:.0f} mm apart)",
        f"final pose:         A {_pose(a.final_pose)}; B {_pose(b.final_pose)}",
        f"final pose error:   {cmp.final_pose_error_mm:.1f} mm, heading {heading:+.1f} deg (B - A)",
        f"path length:        A {a.path_mm / 1000:.3f} m, B {b.path_mm / 1000:.3f} m",
        f"path length ratio:  {ratio} (B / A)",
        f"collisions:         A {a.collisions} ({a.contact_s:.1f} s in contact), "
        f"B {b.collisions} ({b.contact_s:.1f} s in contact)"
        + (f", on {cmp.map_from}'s map" if cmp.map_from else ", no map"),
        f"aligned samples:    {cmp.aligned_samples} over {cmp.aligned_span_s:.1f} s "
        "(B interpolated at A's sample times)",
        f"IR mean difference:        {_per_sensor(cmp.ir_mean_diff)} (B - A, sensors 0..7)",
        f"IR mean |difference|:      {_per_sensor(cmp.ir_mean_abs_diff, signed=False)}",
        f"ambient mean difference:   {_per_sensor(cmp.ambient_mean_diff)} (B - A, sensors 0..7)",
        f"ambient mean |difference|: {_per_sensor(cmp.ambient_mean_abs_diff, signed=False)}",
    ]
    lines += [f"warning:            {w}" for w in cmp.warnings]
    return lines
