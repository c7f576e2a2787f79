"""Plots of a run (PNG, matplotlib): the trajectory over the map, IR and wheel speeds over time;
and of two runs compared (sim beside real): both trajectories on one map, sensors overlaid.

matplotlib is optional (the ``test`` extra): :func:`available` says whether
plots can be drawn; the summary's numbers never need it.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from typing import Any

import numpy as np

from common.messages import WorldSnapshot
from common.recording.compare import SENSORS, Comparison, aligned_samples, robot_track
from common.recording.reader import Recording

# The web view's colours (viewers/web/world_view.py: a robot's body with its gripper
# open, obstacles, balls), so a thing has one colour in the page and in its plots;
# tests/unit/viewers/web/test_parts.py keeps the two the same.
ROBOT_COLOUR = "#4682dc"
OBSTACLE_COLOUR = "#6e6e78"
BALL_COLOUR = "#dc3c3c"


def available() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


def write_plots(rec: Recording, out_dir: Path, stem: str) -> list[Path]:
    """``<stem>.trajectory.png`` and ``<stem>.sensors.png`` in ``out_dir``; the paths written."""
    import matplotlib  # optional (the plots only): a lab without it reports numbers

    matplotlib.use("Agg")  # files only: no display, no GUI toolkit
    import matplotlib.pyplot as plt

    assert rec.info is not None
    agent = rec.info.agent
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []

    fig, ax = plt.subplots(figsize=(7, 6))
    _map(ax, rec)
    xy = [
        (f.record.x[i], f.record.y[i])
        for f in rec.frames
        if (i := _row(f.record.rows, agent)) is not None
    ]
    if xy:
        track = np.array(xy)
        ax.plot(track[:, 0], track[:, 1], "-", lw=1.5, color=ROBOT_COLOUR, label=agent)
        ax.plot(*track[0], "o", color="black", mfc="white", label="start")
        ax.plot(*track[-1], "s", color="black", label="end")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"{rec.info.request_id}: {agent} on {rec.info.world}")
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, out_dir / f"{stem}.trajectory.png"))

    fig, (ir, wheels) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    if rec.samples:
        t0 = rec.samples[0].record.sim_time
        t = np.array([x.record.sim_time - t0 for x in rec.samples])
        prox = np.array([x.record.proximity for x in rec.samples])
        for k in range(prox.shape[1]):
            ir.plot(t, prox[:, k], lw=0.8, label=f"IR{k}")
        speeds = np.array([x.record.speeds for x in rec.samples])
        wheels.plot(t, speeds[:, 0], lw=1, label="left (measured)")
        wheels.plot(t, speeds[:, 1], lw=1, label="right (measured)")
        ir.legend(ncol=4, fontsize=7)
        wheels.legend(fontsize=7)
    ir.set_ylabel("proximity (raw)")
    wheels.set_ylabel("wheel speed")
    wheels.set_xlabel("time (s)")
    ir.set_title(f"{rec.info.request_id}: sensors and wheels of {agent}")
    written.append(_save(fig, out_dir / f"{stem}.sensors.png"))
    return written


def _save(fig: Any, path: Path, dpi: int = 110) -> Path:
    """Write the figure, then close it (pyplot holds every open figure until closed)."""
    import matplotlib.pyplot as plt  # optional: already loaded by the caller that drew ``fig``

    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def _row(rows: list[str], agent: str) -> int | None:
    try:
        return rows.index(agent)
    except ValueError:
        return None


def _map(ax: Any, rec: Recording) -> None:
    _draw_map(ax, rec.snapshot)


def _draw_map(ax: Any, snap: WorldSnapshot | None) -> None:
    if snap is None:
        return
    from matplotlib.patches import Circle, Polygon, Rectangle  # optional, as above

    ax.add_patch(Rectangle((0, 0), snap.width, snap.height, fill=False, lw=1.5, color="black"))
    for item in snap.items:
        face = {"obstacle": OBSTACLE_COLOUR, "zone": "#c8e6c9", "object": BALL_COLOUR}[
            item.category
        ]
        if item.shape.kind == "circle":
            ax.add_patch(Circle((item.x, item.y), item.shape.radius, color=face, alpha=0.8))
        else:
            c, s = math.cos(item.heading), math.sin(item.heading)
            pts = [
                (item.x + c * px - s * py, item.y + s * px + c * py) for px, py in item.shape.points
            ]
            ax.add_patch(Polygon(pts, closed=True, color=face, alpha=0.8))
    ax.set_xlim(-20, snap.width + 20)
    ax.set_ylim(-20, snap.height + 20)


def write_comparison_plots(
    a: Recording, b: Recording, cmp: Comparison, out_dir: Path, stem: str
) -> list[Path]:
    """``<stem>.trajectories.png`` (both runs on one map) and ``<stem>.sensors.png`` (each IR
    and ambient sensor of both runs over the slot's time, overlaid) in ``out_dir``."""
    import matplotlib  # optional (the plots only)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    ta, tb = robot_track(a), robot_track(b)
    written = []

    fig, ax = plt.subplots(figsize=(7, 6))
    snap = a.snapshot if cmp.map_from == cmp.a.label else b.snapshot
    _draw_map(ax, snap)
    # A drawn wide and pale under B, so where the two runs agree both stay visible.
    for tr, side, colour, width in ((ta, cmp.a, "tab:blue", 4.0), (tb, cmp.b, "tab:orange", 1.5)):
        ax.plot(
            tr.x,
            tr.y,
            "-",
            lw=width,
            alpha=0.6 if width > 2 else 1.0,
            color=colour,
            label=f"{side.label} ({side.world})",
        )
        ax.plot(tr.x[0], tr.y[0], "o", color=colour, mfc="white")
        ax.plot(tr.x[-1], tr.y[-1], "s", color=colour)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(
        f"{cmp.a.label} vs {cmp.b.label}: final pose error {cmp.final_pose_error_mm:.0f} mm "
        "(o start, \u25a0 end)"
    )
    ax.legend(loc="upper right", fontsize=8)
    written.append(_save(fig, out_dir / f"{stem}.trajectories.png"))

    fig, axes = plt.subplots(SENSORS, 2, figsize=(11, 12), sharex=True)
    for col, (kind, first) in enumerate((("IR", 0), ("ambient", SENSORS))):
        for k in range(SENSORS):
            ax = axes[k, col]
            for tr, side, colour in ((ta, cmp.a, "tab:blue"), (tb, cmp.b, "tab:orange")):
                values = tr.proximity if first == 0 else tr.ambient
                if len(tr.sample_t):
                    ax.plot(tr.sample_t, values[:, k], lw=0.8, color=colour, label=side.label)
            ax.set_ylabel(f"{kind}{k}", fontsize=8)
            ax.tick_params(labelsize=7)
        axes[0, col].set_title(f"{kind} (raw)")
        axes[-1, col].set_xlabel("time since the slot's start (s)")
    # The numbers beside the curves: the mean difference over the time-aligned samples.
    t, _, _ = aligned_samples(ta, tb)
    for col, diffs in enumerate((cmp.ir_mean_diff, cmp.ambient_mean_diff)):
        for k, d in enumerate(diffs):
            axes[k, col].text(
                0.99,
                0.9,
                f"{cmp.b.label} - {cmp.a.label}: {d:+.1f} on average",
                transform=axes[k, col].transAxes,
                ha="right",
                va="top",
                fontsize=7,
            )
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"sensors overlaid ({len(t)} time-aligned samples)")
    written.append(_save(fig, out_dir / f"{stem}.sensors.png", dpi=100))
    return written
