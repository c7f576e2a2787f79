"""A differential-drive robot's motion from its commands: what the twin predicts.

The model a Khepera's datasheet gives, with the parameters a real one differs by:
each wheel moves ``scale`` times what its command says (slip, a worn tyre), the
wheels sit ``wheel_base_mm`` apart, and a command moves them ``latency_s`` after the
lab sent it. Integrated open-loop from a known pose, many windows at once (numpy):
the fit (common/twin/fit.py) compares it with the camera's poses, and the gap
report runs it from a real run's start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.sim2d.agents.khepera import DRIVE

F64 = npt.NDArray[np.float64]
MM_S_PER_UNIT = DRIVE.mm_per_pulse / DRIVE.unit_time_s  # a Khepera: 8 mm/s a speed unit
SUBSTEPS = 40  # integration steps per window (25 ms over a 1 s window)


@dataclass(frozen=True)
class Drive:
    """The parameters of the motion model (the datasheet's by default)."""

    scale_left: float = 1.0
    scale_right: float = 1.0
    wheel_base_mm: float = DRIVE.wheel_base_mm
    latency_s: float = 0.0

    def as_array(self) -> F64:
        return np.array([self.scale_left, self.scale_right, self.wheel_base_mm, self.latency_s])

    @classmethod
    def of(cls, values: F64) -> Drive:
        return cls(float(values[0]), float(values[1]), float(values[2]), float(values[3]))


def commanded(commands: F64, start: F64, end: F64, latency_s: float) -> tuple[F64, F64]:
    """Each wheel's mean command over [``start``, ``end``) (rows of ``commands``: t, left,
    right), as obeyed ``latency_s`` after it was sent; before the first command the wheels
    stand. A mean, not the command at one instant: the fit's residuals then change
    smoothly with the latency, which a least-squares fit needs."""
    t = commands[:, 0]
    values = commands[:, 1:3]
    # The integral of the command up to each command's time (piecewise constant between).
    area = np.vstack([np.zeros((1, 2)), np.cumsum(values[:-1] * np.diff(t)[:, None], axis=0)])

    def integral(at: F64) -> F64:
        k = np.searchsorted(t, at, side="right") - 1
        inside = k >= 0
        kk = np.clip(k, 0, None)
        out = area[kk] + values[kk] * (at - t[kk])[:, None]
        return np.where(inside[:, None], out, 0.0)

    span = np.maximum(end - start, 1e-9)
    mean = (integral(end - latency_s) - integral(start - latency_s)) / span[:, None]
    return mean[:, 0], mean[:, 1]


def predict(drive: Drive, commands: F64, start: F64, t0: F64, t1: F64) -> F64:
    """Poses (W, 3: x mm, y mm, heading rad) at ``t1`` of W windows, each from the pose
    ``start[w]`` at ``t0[w]``, driven open-loop by ``commands``."""
    x, y, h = (start[:, i].astype(float).copy() for i in range(3))
    dt = (t1 - t0) / SUBSTEPS
    for k in range(SUBSTEPS):
        left, right = commanded(commands, t0 + k * dt, t0 + (k + 1) * dt, drive.latency_s)
        vl = MM_S_PER_UNIT * drive.scale_left * left
        vr = MM_S_PER_UNIT * drive.scale_right * right
        v, w = (vl + vr) / 2.0, (vr - vl) / drive.wheel_base_mm
        heading = h + w * dt / 2.0  # the midpoint's heading: exact for a constant turn's chord
        x += v * np.cos(heading) * dt
        y += v * np.sin(heading) * dt
        h += w * dt
    return np.stack([x, y, h], axis=1)


def wrap(angle: F64) -> F64:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def ahead(drive: Drive, pose: F64, speeds: tuple[float, float], times: F64) -> F64:
    """Poses (T, 3) at ``times`` (seconds from now) of a robot at ``pose`` whose wheels keep
    turning at ``speeds`` (the type's unit, as its odometry reads them): the ghost the page
    draws ahead of a live robot. The wheels already turn at those speeds, so no latency;
    each wheel's slip and the wheel base are the drive's. Exact for constant speeds (an
    arc): :func:`predict` given one constant command agrees to its integration step."""
    vl = MM_S_PER_UNIT * drive.scale_left * float(speeds[0])
    vr = MM_S_PER_UNIT * drive.scale_right * float(speeds[1])
    v, w = (vl + vr) / 2.0, (vr - vl) / drive.wheel_base_mm
    x0, y0, h0 = (float(value) for value in pose[:3])
    t = np.asarray(times, np.float64)
    h = h0 + w * t
    if abs(w) < 1e-9:  # straight on
        x, y = x0 + v * t * math.cos(h0), y0 + v * t * math.sin(h0)
    else:
        r = v / w
        x, y = x0 + r * (np.sin(h) - math.sin(h0)), y0 - r * (np.cos(h) - math.cos(h0))
    return np.stack([np.broadcast_to(x, t.shape), np.broadcast_to(y, t.shape), h], axis=1)
