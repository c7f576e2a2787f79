"""What a model's sensors read along a real run, and how far that is from what the robot read.

The simulator's own sensor model (the kernels a simulated robot's sensors run, noise
off) is read at each recorded sample's pose, the camera's poses on either side of it
interpolated, in the run's arena rebuilt from its recording's snapshot (walls,
obstacles, lights: common/twin/arena.py). The robot type is a robot file's: the
datasheet Khepera's, or a twin's (each IR sensor's fitted gain), so "what the model
reads" is what a simulated copy of the robot would have read on the real path.

The fit (common/twin/fit.py) takes the datasheet's readings to find each sensor's
gain; the sensor gap compares each model's readings with the recorded ones, sensor
by sensor (:func:`sensor_gap`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.messages import WorldSnapshot
from common.sim2d.maps import MapError
from common.sim2d.world import EditError
from common.twin.arena import sensing_world
from common.twin.motion import F64, wrap

SENSORS = 8
NEAR_READING = 30.0  # an IR reading this high: the sensor sees something
PLACES = 10  # camera poses tried to place the robot in the rebuilt arena
# The robot file's keys of its sensors' noise: set to 0, or left out (each sensor's own).
_NOISE_OFF = ("noise_fraction", "noise_counts")
_NOISE_EACH = "sensor_noise_counts"


def quiet(robot_file: str) -> str:
    """``robot_file`` with every sensor's noise off: the model's readings, not one draw."""
    lines = []
    for line in robot_file.splitlines():
        key = line.split("=")[0].strip() if "=" in line else ""
        if key == _NOISE_EACH:
            continue  # one line: a twin's robot file writes it so (common/twin/twinfile.py)
        lines.append(f"{key} = 0.0" if key in _NOISE_OFF else line)
    return "\n".join(lines) + "\n"


def poses_at(poses: F64, times: F64, most_s: float = 0.5) -> F64:
    """(P, 3): the pose at each of ``times``, between the camera poses (rows t, x, y,
    heading) on either side of it; NaN where the camera saw the robot on one side only,
    or not within ``most_s``."""
    t = poses[:, 0]
    out = np.full((len(times), 3), np.nan)
    j = np.searchsorted(t, times)
    ok = (j > 0) & (j < len(t))
    j = np.clip(j, 1, max(1, len(t) - 1))
    ok &= t[j] - t[j - 1] <= most_s
    f = (times - t[j - 1]) / np.maximum(t[j] - t[j - 1], 1e-9)
    xy = (1 - f)[:, None] * poses[j - 1, 1:3] + f[:, None] * poses[j, 1:3]
    h = poses[j - 1, 3] + f * wrap(poses[j, 3] - poses[j - 1, 3])
    out[ok] = np.column_stack([xy, h])[ok]
    return out


def model_readings(
    snap: WorldSnapshot | None,
    agent: str,
    robot: tuple[str, str],
    poses: F64,
    times: F64,
) -> tuple[F64, F64]:
    """(P, 8) IR and (P, 8) ambient readings of the robot type ``robot`` (name, robot
    file; its noise is turned off here) at each of ``times`` along the camera's
    ``poses``; NaN rows where there is no pose, or it touches a wall or obstacle (the
    camera's pose is off by a millimetre or two), or there is no snapshot of the arena
    (or none of the arena the robot could be placed in)."""
    ir = np.full((len(times), SENSORS), np.nan)
    ambient = np.full((len(times), SENSORS), np.nan)
    if snap is None or snap.width <= 0 or snap.height <= 0 or not len(times) or not len(poses):
        return ir, ambient
    at = poses_at(poses, times)
    world = None
    # Built with the robot where the camera saw it (so where it fits), the first of a few
    # such poses that touches nothing (the camera's pose is off by a millimetre or two).
    for start in poses[:: max(1, len(poses) // PLACES)][:PLACES]:
        try:
            world = sensing_world(snap, agent, robot[0], quiet(robot[1]), tuple(start[1:4]))
            break
        except (MapError, EditError):
            continue
    if world is None:
        return ir, ambient
    for k in np.nonzero(np.isfinite(at[:, 0]))[0]:
        x, y, h = at[k]
        try:
            world.move(agent, float(x), float(y), float(h))
        except EditError:
            continue
        world.sense()
        ir[k] = world.proximity[0, :SENSORS]
        ambient[k] = world.ambient[0, :SENSORS]
    return ir, ambient


@dataclass(frozen=True)
class SensorError:
    """One model's median absolute error (counts) per sensor against the recorded readings;
    None: no reading to compare (an IR sensor that saw nothing, ambient not recorded)."""

    model: str
    ir: tuple[float | None, ...]
    ambient: tuple[float | None, ...]

    @staticmethod
    def _figures(errors: tuple[float | None, ...]) -> str:
        return " / ".join("-" if e is None else f"{e:.0f}" for e in errors)

    def ir_line(self) -> str:
        return f"{self.model}: {self._figures(self.ir)}"

    def ambient_line(self) -> str:
        return f"{self.model}: {self._figures(self.ambient)}"


def _medians(model: F64, recorded: F64, rows: np.ndarray) -> tuple[float | None, ...]:
    out: list[float | None] = []
    for i in range(SENSORS):
        use = rows[:, i] & np.isfinite(model[:, i]) & np.isfinite(recorded[:, i])
        out.append(
            float(np.median(np.abs(model[use, i] - recorded[use, i]))) if use.any() else None
        )
    return tuple(out)


def sensor_errors(models: list[tuple[str, F64, F64]], ir: F64, ambient: F64) -> list[SensorError]:
    """Each model's (name, IR readings, ambient readings) error against the recorded ``ir``
    and ``ambient`` (P, 8; NaN: not recorded). IR over the samples where the robot or any
    of the models read at least :data:`NEAR_READING` on that sensor, the same samples for
    every model (away from everything every model reads 0, and so does the robot: an
    error of 0 that says nothing); ambient over every sample."""
    near = ir >= NEAR_READING
    for _, model_ir, _ in models:
        near |= model_ir >= NEAR_READING
    everywhere = np.ones_like(near)
    return [
        SensorError(name, _medians(model_ir, ir, near), _medians(model_amb, ambient, everywhere))
        for name, model_ir, model_amb in models
    ]
