"""A real robot's parameters, fitted from its recorded runs: the twin's numbers.

Each run on a real arena is recorded on one clock (common/recording/): the commands
the robot obeyed, the arena camera's poses of it, its IR readings. From those:

- **the drive** (each wheel's scale, the wheel base, the command-to-motion latency):
  from every camera pose, the motion model (common/twin/motion.py) is run open-loop
  on the recorded commands for ``WINDOW_S`` and compared with the camera's pose
  then; scipy's ``least_squares`` finds the parameters that make those gaps least;
- **each IR sensor's gain and noise**: the datasheet's sensor model (the simulator's,
  noise off) read at each recorded pose in the run's arena (its walls and obstacles,
  from the recording's snapshot: common/twin/readings.py) says what a datasheet
  Khepera would have read; each sensor's gain is the least-
  squares ratio of what it read to that (numpy's ``lstsq``), its noise what is left.

Each value comes with its standard error (from the fit's Jacobian, inflated for the
windows' overlap) and the runs that constrained it. A parameter the runs cannot
constrain is refused with the reason (a robot that only drove straight says
nothing about its wheel base) and kept at the datasheet's value for the others.
The ambient sensors are not fitted: that needs readings under a lamp at a known
place, which a recording of a real arena does not have.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from common.messages import WorldSnapshot
from common.recording.reader import Recording
from common.twin.motion import F64, Drive, predict, wrap
from common.twin.readings import NEAR_READING, model_readings

WINDOW_S = 1.0  # how far each open-loop prediction runs before it is compared
HEADING_MM = 30.0  # a radian of heading weighs as this many mm of position
START_LATENCY_S = 0.03  # where the latency's search starts
ROBUST_MM = 3.0  # residuals beyond this count less and less (soft L1)
MIN_PATH_MM = 150.0  # less travel than this says nothing about the drive
MIN_TURN_RAD = math.pi / 2  # the wheel base needs this much turning...
MIN_APART_S = 1.0  # ...while the wheels are commanded apart this long
MIN_CHANGES = 4  # the latency needs this many changes of command while moving
MIN_NEAR = 15  # an IR sensor's gain needs this many readings near a wall
SENSORS = 8
# The datasheet model's IR noise (common/robots/shipped/khepera.toml): a fraction of the
# reading plus a few counts.
NOISE_FRACTION, NOISE_COUNTS = 0.03, 2.0
# The standard error above which a value is said to be not constrained by the runs.
LOOSE = {"scale_left": 0.05, "scale_right": 0.05, "wheel_base_mm": 6.0, "latency_s": 0.06}
SHIPPED_KHEPERA = Path(__file__).resolve().parents[2] / "common/robots/shipped/khepera.toml"


class TwinError(ValueError):
    """Recordings that cannot be fitted at all: the reason, in words."""


@dataclass
class Estimate:
    name: str
    value: float
    sigma: float | None  # None: refused (kept at the datasheet's value)
    datasheet: float
    unit: str
    runs: list[str] = field(default_factory=list)
    refused: str = ""  # why it was not fitted

    def line(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.refused:
            return f"{self.name}: not fitted ({self.refused}); datasheet {self.datasheet:g}{unit}"
        sigma = self.sigma or 0.0
        return (
            f"{self.name}: {self.value:.4g} ± {sigma:.2g}{unit} (datasheet {self.datasheet:g}; "
            f"from {', '.join(self.runs)})"
        )


@dataclass
class RunData:
    name: str
    agent: str
    commands: F64  # (K, 3): t, left, right (speed units)
    poses: F64  # (M, 4): t, x mm, y mm, heading rad (the camera's)
    samples: F64  # (P, 9): t, the 8 IR readings
    ambient: F64  # (P, 8): the 8 ambient readings of the same samples (NaN: not recorded)
    snapshot: WorldSnapshot | None  # the arena, as the run's recording saw it at its start

    @property
    def arena(self) -> tuple[float, float]:
        """The arena's width and height (mm); 0, 0 without a snapshot of it."""
        snap = self.snapshot
        return (snap.width, snap.height) if snap is not None else (0.0, 0.0)

    @property
    def path_mm(self) -> float:
        return float(np.hypot(*np.diff(self.poses[:, 1:3], axis=0).T).sum())

    @property
    def turn_rad(self) -> float:
        return float(np.abs(wrap(np.diff(self.poses[:, 3]))).sum())

    @property
    def apart_s(self) -> float:
        """Time the wheels were commanded at least 2 units apart."""
        dt = np.diff(np.append(self.commands[:, 0], self.poses[-1, 0]))
        apart = np.abs(self.commands[:, 2] - self.commands[:, 1]) >= 2
        return float(np.clip(dt, 0, None)[apart].sum())

    @property
    def changes(self) -> int:
        jumps = np.abs(np.diff(self.commands[:, 1:], axis=0)).max(axis=1, initial=0)
        return int((jumps >= 2).sum())


def run_data(rec: Recording, name: str) -> RunData:
    """One recording's commands, camera poses and IR readings of its robot (TwinError: why not)."""
    if rec.info is None:
        raise TwinError(f"{name} is not a run's recording (no run info)")
    agent = rec.info.agent
    cmds = [(s.t, *s.record.speeds) for s in rec.commands if s.record.speeds is not None]
    poses = [
        (s.t, r.x, r.y, r.heading) for s in rec.tracked for r in s.record.robots if r.agent == agent
    ]
    rows = sorted(((s.t, s.record) for s in rec.samples
                   if s.record.agent == agent and len(s.record.proximity) >= SENSORS),
                  key=lambda row: row[0])  # fmt: skip
    samples = [(t, *r.proximity[:SENSORS]) for t, r in rows]
    ambient = [r.ambient[:SENSORS] if len(r.ambient) >= SENSORS else [math.nan] * SENSORS
               for _, r in rows]  # fmt: skip
    if len(poses) < 10:
        raise TwinError(
            f"{name} has {len(poses)} camera pose(s) of {agent}: calibrating needs the arena "
            "camera's view of the robot (a run on a real arena watched by `wart camera`)"
        )
    if not cmds:
        raise TwinError(f"{name} has no command of {agent}: nothing drove it")
    return RunData(
        name,
        agent,
        np.array(sorted(cmds), dtype=float),
        np.array(sorted(poses), dtype=float),
        np.array(samples, dtype=float).reshape(-1, 1 + SENSORS),
        np.array(ambient, dtype=float).reshape(-1, SENSORS),
        rec.snapshot,
    )


@dataclass
class Windows:
    """The open-loop windows of one run: from camera pose ``a`` to camera pose ``b``."""

    run: RunData
    a: np.ndarray
    b: np.ndarray

    @classmethod
    def of(cls, run: RunData, seconds: float = WINDOW_S) -> Windows:
        t = run.poses[:, 0]
        ends = np.searchsorted(t, t + seconds)
        last = np.minimum(ends, len(t) - 1)
        ok = (ends < len(t)) & (t[last] - t <= 1.5 * seconds)
        # Only windows in which the robot was driven: standing before and after the run
        # says nothing of the drive, and would make every error look small.
        driven = np.abs(run.commands[:, 1:]).sum(axis=1) > 0
        first = np.searchsorted(run.commands[:, 0], t - 0.5)
        upto = np.searchsorted(run.commands[:, 0], t[last], side="right")
        cumulative = np.concatenate([[0], np.cumsum(driven)])
        ok &= cumulative[upto] - cumulative[first] > 0
        starts = np.nonzero(ok)[0]
        return cls(run, starts, ends[starts])

    def residuals(self, drive: Drive) -> F64:
        p = self.run.poses
        got = predict(drive, self.run.commands, p[self.a, 1:4], p[self.a, 0], p[self.b, 0])
        seen = p[self.b, 1:4]
        return np.concatenate([
            got[:, 0] - seen[:, 0],
            got[:, 1] - seen[:, 1],
            HEADING_MM * wrap(got[:, 2] - seen[:, 2]),
        ])  # fmt: skip


NAMES = ("scale_left", "scale_right", "wheel_base_mm", "latency_s")
UNITS = ("", "", "mm", "s")
LOW, HIGH = np.array([0.5, 0.5, 30.0, 0.0]), np.array([1.5, 1.5, 80.0, 0.5])


def fit_drive(runs: list[RunData]) -> list[Estimate]:
    """The drive's four parameters from the runs, each fitted or refused with the reason."""
    datasheet = Drive()
    base = datasheet.as_array()
    moving = [r for r in runs if r.path_mm >= 50.0]
    path = sum(r.path_mm for r in runs)
    turning = [r for r in runs if r.apart_s >= 0.3 and r.turn_rad >= 0.3]
    changing = [r for r in moving if r.changes >= 2]
    why: dict[str, str] = {}
    if path < MIN_PATH_MM:
        for name in NAMES:
            why[name] = f"the robot moved {path:.0f} mm in these runs: at least {MIN_PATH_MM:g}"
    turn = sum(r.turn_rad for r in runs)
    apart = sum(r.apart_s for r in runs)
    if turn < MIN_TURN_RAD or apart < MIN_APART_S:
        why.setdefault(
            "wheel_base_mm",
            f"the robot turned {math.degrees(turn):.0f}° with its wheels commanded apart for "
            f"{apart:.1f} s; the wheel base needs turns ({math.degrees(MIN_TURN_RAD):.0f}° "
            f"and {MIN_APART_S:g} s)",
        )
    changes = sum(r.changes for r in moving)
    if changes < MIN_CHANGES:
        why.setdefault(
            "latency_s",
            f"the commands changed {changes} time(s) while the robot moved; the latency needs "
            f"{MIN_CHANGES} changes",
        )
    free = [i for i, name in enumerate(NAMES) if name not in why]
    windows = [Windows.of(r) for r in runs]
    values, sigma = base.copy(), np.full(len(NAMES), np.nan)
    if free:

        def residuals(x: F64) -> F64:
            p = base.copy()
            p[free] = x
            return np.concatenate([w.residuals(Drive.of(p)) for w in windows])

        # A robust loss: a window in which the robot touched something (a wall, a ball, a
        # hand) is not the drive's doing, and must not pull the fit.
        start = base.copy()
        start[3] = START_LATENCY_S  # inside its bounds: from the bound itself the fit stayed there
        # scipy.optimize is imported at the fit, not with the module: it is about 0.8 s
        # of a process's start, and the web viewer imports this module with its
        # recordings panel, where few sessions ever calibrate.
        from scipy.optimize import least_squares

        fitted = least_squares(
            residuals,
            start[free],
            bounds=(LOW[free], HIGH[free]),
            x_scale="jac",
            diff_step=1e-3,
            loss="soft_l1",
            f_scale=ROBUST_MM,
        )
        values[free] = fitted.x
        m, n = fitted.fun.size, len(free)
        # The windows overlap (one starts at every camera pose): neighbouring residuals are
        # far from independent, so the textbook standard error is scaled up by how many
        # windows cover each instant.
        seconds = sum(r.poses[-1, 0] - r.poses[0, 0] for r in runs)
        overlap = max(1.0, sum(len(w.a) for w in windows) * WINDOW_S / max(1e-9, seconds))
        jac = fitted.jac
        try:
            cov = np.linalg.inv(jac.T @ jac) * (2 * fitted.cost / max(1, m - n)) * overlap
            sigma[free] = np.sqrt(np.clip(np.diag(cov), 0, None))
        except np.linalg.LinAlgError:
            sigma[free] = np.inf
        for i in free:
            if not sigma[i] <= LOOSE[NAMES[i]]:
                why[NAMES[i]] = f"not constrained by these runs (± {sigma[i]:.2g})"
                values[i] = base[i]
    constrained = {
        "scale_left": moving,
        "scale_right": moving,
        "wheel_base_mm": turning,
        "latency_s": changing,
    }
    return [
        Estimate(
            name,
            float(values[i]) if name not in why else float(base[i]),
            None if name in why else float(sigma[i]),
            float(base[i]),
            UNITS[i],
            [r.name for r in constrained[name]],
            why.get(name, ""),
        )
        for i, name in enumerate(NAMES)
    ]


def datasheet_readings(run: RunData) -> F64:
    """(P, 8): what a datasheet Khepera reads at each sample's camera pose, in the run's
    arena (NaN: no pose; common/twin/readings.py)."""
    khepera = SHIPPED_KHEPERA.read_text().replace('name = "khepera"', 'name = "khepera_clean"')
    ir, _ = model_readings(
        run.snapshot, run.agent, ("khepera_clean", khepera), run.poses, run.samples[:, 0]
    )
    return ir


def fit_proximity(runs: list[RunData]) -> list[Estimate]:
    """Each IR sensor's gain against the datasheet curve, and its noise (counts)."""
    pred = [datasheet_readings(r) for r in runs]
    out: list[Estimate] = []
    for i in range(SENSORS):
        p = np.concatenate([q[:, i] for q in pred])
        r = np.concatenate([run.samples[:, 1 + i] for run in runs])
        near = np.isfinite(p) & (p >= NEAR_READING)
        used = [run.name for run, q in zip(runs, pred, strict=True)
                if (np.isfinite(q[:, i]) & (q[:, i] >= NEAR_READING)).sum() > 0]  # fmt: skip
        if near.sum() < MIN_NEAR:
            reason = (
                f"it saw a wall in {int(near.sum())} reading(s); the gain needs {MIN_NEAR} "
                "(drive past a wall with this side)"
            )
            out.append(Estimate(f"ir{i}_gain", 1.0, None, 1.0, "", used, reason))
            continue
        a = p[near][:, None]
        (gain,), _res, _rank, _sv = np.linalg.lstsq(a, r[near], rcond=None)
        left = r[near] - gain * p[near]
        noise = float(np.std(left))
        sigma = noise / math.sqrt(float((p[near] ** 2).sum()))
        out.append(Estimate(f"ir{i}_gain", float(gain), sigma, 1.0, "", used))
        # The noise with the camera's pose error in it: an upper bound on the sensor's own;
        # beside it, what the datasheet model's noise is at the same readings.
        noise_sigma = noise / math.sqrt(2.0 * max(1, int(near.sum()) - 1))
        model = math.sqrt(float(np.mean((NOISE_FRACTION * gain * p[near]) ** 2)) + NOISE_COUNTS**2)
        out.append(Estimate(f"ir{i}_noise", noise, noise_sigma, round(model, 1), "counts", used))
    return out


@dataclass
class Calibration:
    robot: str
    runs: list[str]
    drive: list[Estimate]
    proximity: list[Estimate]
    ambient: str = (
        "not fitted: the ambient sensors' response needs readings under a lamp at a known "
        "place, which a real arena's recording does not have"
    )

    def fitted_drive(self) -> Drive:
        return Drive(*(e.value for e in self.drive))

    def lines(self) -> list[str]:
        return [e.line() for e in (*self.drive, *self.proximity)] + [f"ambient: {self.ambient}"]

    def to_json(self, who: str, when: float) -> str:
        def entry(e: Estimate) -> dict[str, object]:
            return {"value": e.value, "sigma": e.sigma, "datasheet": e.datasheet, "unit": e.unit,
                    "runs": e.runs, "refused": e.refused}  # fmt: skip

        return json.dumps(
            {
                "format": "wart-twin",
                "version": 1,
                "robot": self.robot,
                "fitted_by": who,
                "fitted_at": when,
                "runs": self.runs,
                "parameters": {e.name: entry(e) for e in (*self.drive, *self.proximity)},
                "ambient": self.ambient,
            },
            indent=2,
        )


def calibrate(robot: str, recordings: list[tuple[str, Recording]]) -> Calibration:
    """Fit ``robot``'s twin from its recorded runs (TwinError when none can be used)."""
    runs: list[RunData] = []
    problems: list[str] = []
    for name, rec in recordings:
        try:
            run = run_data(rec, name)
        except TwinError as exc:
            problems.append(str(exc))
            continue
        if run.agent != robot:
            problems.append(f"{name} is a run of {run.agent}, not {robot}")
            continue
        runs.append(run)
    if not runs:
        raise TwinError("no recording can be used: " + "; ".join(problems))
    return Calibration(robot, [r.name for r in runs], fit_drive(runs), fit_proximity(runs))


def open_loop_error(drive: Drive, run: RunData, seconds: float) -> float:
    """Median position error (mm) of ``drive`` run open-loop for ``seconds`` from each camera
    pose of ``run``: how far the model strays from the real robot in that time."""
    w = Windows.of(run, seconds)
    if not len(w.a):
        return math.nan
    p = run.poses
    got = predict(drive, run.commands, p[w.a, 1:4], p[w.a, 0], p[w.b, 0])
    return float(np.median(np.hypot(got[:, 0] - p[w.b, 1], got[:, 1] - p[w.b, 2])))
