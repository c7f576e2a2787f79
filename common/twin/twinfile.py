"""A twin file: a real robot's fitted parameters as JSON (``wart calibrate --out``), checked.

Written by :meth:`common.twin.fit.Calibration.to_json`; read back wherever a twin
comes in from outside (a file a teacher hands ``wart twin save``, a row of the
lab's database), so every field is checked here, with its range, and a file that
fails is refused whole with every problem named. A checked twin makes the robot
file of a simulated copy of its robot: the shipped Khepera with the fitted drive
(each wheel's scale, the wheel base, the command latency; common/sim2d/specs.py) and
each IR sensor's fitted gain and noise (``sensor_gains``, ``sensor_noise_counts``).
"""

from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.twin.motion import Drive

FORMAT = "wart-twin"
VERSION = 1
MAX_BYTES = 64 * 1024
MAX_RUNS = 100
SENSORS = 8
SHIPPED_KHEPERA = Path(__file__).resolve().parents[2] / "common/robots/shipped/khepera.toml"
_ROBOT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,25}$")
EARLIEST = 946684800.0  # 2000-01-01: a fit dated before is a wrong clock or a forged file
# Each parameter's range: what a Khepera can be (the fit's own bounds for the drive).
RANGES: dict[str, tuple[float, float]] = {
    "scale_left": (0.5, 1.5),
    "scale_right": (0.5, 1.5),
    "wheel_base_mm": (30.0, 80.0),
    "latency_s": (0.0, 0.5),
    **{f"ir{i}_gain": (0.05, 10.0) for i in range(SENSORS)},
    **{f"ir{i}_noise": (0.0, 1023.0) for i in range(SENSORS)},
}
DRIVE = ("scale_left", "scale_right", "wheel_base_mm", "latency_s")
DATASHEET_NOISE_COUNTS = 2.0  # the shipped Khepera's additive IR noise (its noise_counts)
TOP_KEYS = ("format", "version", "robot", "fitted_by", "fitted_at", "runs", "parameters",
            "ambient")  # fmt: skip
ENTRY_KEYS = ("value", "sigma", "datasheet", "unit", "runs", "refused")


class TwinFileError(ValueError):
    """A twin file refused: every problem, one a line."""

    def __init__(self, source: str, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("\n".join(f"{source}: {p}" for p in problems))


@dataclass(frozen=True)
class Twin:
    """A checked twin: who fitted which robot when, from which runs, and its drive."""

    robot: str
    fitted_by: str
    fitted_at: float
    runs: tuple[str, ...]
    drive: Drive
    fitted: tuple[str, ...]  # the drive parameters fitted (the others: the datasheet's)
    text: str  # the file, as checked
    # Each IR sensor's gain and additive noise (counts) as its simulated copy reads; empty:
    # no sensor's gain was fitted, the copy reads the datasheet's curve.
    ir_gains: tuple[float, ...] = ()
    ir_noise_counts: tuple[float, ...] = ()

    @property
    def day(self) -> str:
        return time.strftime("%Y-%m-%d", time.gmtime(self.fitted_at))

    def model(self) -> str:
        """What a run simulated with it says: "k1's twin fitted 2026-12-05 by carol"."""
        return f"{self.robot}'s twin fitted {self.day} by {self.fitted_by}"

    @property
    def type_name(self) -> str:
        """The robot type of its simulated copy (a robot file's name: lower case)."""
        return "twin-" + re.sub(r"[^a-z0-9_-]", "-", self.robot.lower())

    def robot_file(self) -> str:
        """The shipped Khepera's robot file with this twin's drive and, where fitted, each IR
        sensor's gain and noise: its simulated copy."""
        d = self.drive
        text = SHIPPED_KHEPERA.read_text()
        drive = (
            f"wheel_base_mm = {d.wheel_base_mm!r}\n"
            f"wheel_scale = [{d.scale_left!r}, {d.scale_right!r}]\n"
            f"latency_s = {d.latency_s!r}"
        )
        sensors = (
            f"noise_counts = {DATASHEET_NOISE_COUNTS!r}\n"
            f"sensor_gains = [{', '.join(repr(g) for g in self.ir_gains)}]\n"
            f"sensor_noise_counts = [{', '.join(repr(n) for n in self.ir_noise_counts)}]"
            if self.ir_gains
            else f"noise_counts = {DATASHEET_NOISE_COUNTS!r}"
        )
        for old, new in (
            ('name = "khepera"', f'name = "{self.type_name}"'),
            ("wheel_base_mm = 53.0", drive),
            (f"noise_counts = {DATASHEET_NOISE_COUNTS!r}", sensors),
        ):
            if old not in text:  # the shipped file changed shape: say so, never half-edit it
                raise RuntimeError(f"{SHIPPED_KHEPERA} has no line {old!r}")
            text = text.replace(old, new, 1)
        lines = text.splitlines()
        lines = [
            f'description = "{self.model()} (wart calibrate)"'
            if line.startswith("description =")
            else line
            for line in lines
        ]
        return "\n".join(lines) + "\n"


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _text(value: Any, most: int) -> bool:
    return isinstance(value, str) and len(value) <= most and value.isprintable()


def parse_twin(data: bytes | str, source: str = "twin file", now: float | None = None) -> Twin:
    """Check a twin file and return it (TwinFileError with every problem)."""
    raw = data.encode() if isinstance(data, str) else data
    if len(raw) > MAX_BYTES:
        raise TwinFileError(source, [f"is {len(raw)} bytes; a twin file is at most {MAX_BYTES}"])
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise TwinFileError(source, [f"is not JSON text: {exc}"]) from None
    if not isinstance(doc, dict):
        raise TwinFileError(source, ["must be a JSON object (wart calibrate --out writes one)"])
    problems: list[str] = []
    for key in doc:
        if key not in TOP_KEYS:
            problems.append(f"{key}: unknown field (a twin file has {', '.join(TOP_KEYS)})")
    if doc.get("format") != FORMAT:
        problems.append(f'format: must be "{FORMAT}", got {doc.get("format")!r}')
    if doc.get("version") != VERSION:
        problems.append(f"version: must be {VERSION}, got {doc.get('version')!r}")
    robot = doc.get("robot")
    if not isinstance(robot, str) or not _ROBOT.match(robot):
        problems.append(f"robot: a robot's name ({_ROBOT.pattern}), got {robot!r}")
    who: Any = doc.get("fitted_by")
    if not _text(who, 64) or not who:
        problems.append(f"fitted_by: who fitted it (a name, at most 64 characters), got {who!r}")
    when: Any = doc.get("fitted_at")
    latest = (time.time() if now is None else now) + 86400.0
    if not _number(when) or not EARLIEST <= when <= latest:
        problems.append(f"fitted_at: when it was fitted (seconds since 1970, not in the "
                        f"future), got {when!r}")  # fmt: skip
    runs = doc.get("runs")
    if (
        not isinstance(runs, list)
        or not runs
        or len(runs) > MAX_RUNS
        or not all(_text(r, 200) and r for r in runs)
    ):
        problems.append(f"runs: the names of 1 to {MAX_RUNS} recorded runs it was fitted from")
    if not _text(doc.get("ambient", ""), 500):
        problems.append("ambient: a text of at most 500 characters")
    params = doc.get("parameters")
    values: dict[str, float] = {}
    fitted: list[str] = []
    if not isinstance(params, dict):
        problems.append("parameters: an object of each parameter's fit is required")
        params = {}
    for name, entry in params.items():
        where = f"parameters.{name}"
        if name not in RANGES:
            problems.append(f"{where}: unknown parameter (known: {', '.join(RANGES)})")
            continue
        if not isinstance(entry, dict):
            problems.append(f"{where}: must be an object ({', '.join(ENTRY_KEYS)})")
            continue
        for key in entry:
            if key not in ENTRY_KEYS:
                problems.append(f"{where}.{key}: unknown field ({', '.join(ENTRY_KEYS)})")
        low, high = RANGES[name]
        value: Any = entry.get("value")
        if not _number(value) or not low <= value <= high:
            problems.append(f"{where}.value: a number from {low:g} to {high:g}, got {value!r}")
        else:
            values[name] = float(value)
        sigma: Any = entry.get("sigma")
        if sigma is not None and (not _number(sigma) or sigma < 0):
            problems.append(f"{where}.sigma: null or a number at least 0, got {sigma!r}")
        if not _number(entry.get("datasheet")):
            problems.append(f"{where}.datasheet: a number, got {entry.get('datasheet')!r}")
        if not _text(entry.get("unit", ""), 16):
            problems.append(f"{where}.unit: a text of at most 16 characters")
        used = entry.get("runs", [])
        if (
            not isinstance(used, list)
            or len(used) > MAX_RUNS
            or not all(_text(r, 200) for r in used)
        ):
            problems.append(f"{where}.runs: a list of at most {MAX_RUNS} run names")
        refused = entry.get("refused", "")
        if not _text(refused, 500):
            problems.append(f"{where}.refused: a text of at most 500 characters")
        elif not refused and sigma is not None and name in DRIVE:
            fitted.append(name)
    for name in DRIVE:
        if name not in params:
            problems.append(f"parameters.{name}: required (the drive's four parameters)")
    if problems:
        raise TwinFileError(source, problems)
    drive = Drive(*(values[name] for name in DRIVE))
    gains, noise = _sensors(params, values)
    return Twin(str(robot), str(who), float(when), tuple(runs), drive, tuple(fitted),  # type: ignore[arg-type]
                raw.decode("utf-8"), gains, noise)  # fmt: skip


def _sensors(
    params: dict[str, Any], values: dict[str, float]
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Each IR sensor's gain and additive noise for the simulated copy (empty: none fitted).

    A sensor whose gain was refused keeps the datasheet's (1, noise_counts). The fitted
    noise is the spread of a sensor's readings about its fitted curve, which the
    simulator draws as a share of the reading plus an additive part: the additive part is
    what makes the two agree at the readings the fit saw (the entry's ``datasheet`` is the
    datasheet model's spread there, its own additive part included)."""

    def fitted(name: str) -> bool:
        entry = params.get(name)
        return isinstance(entry, dict) and not entry.get("refused") and name in values

    sensors = range(SENSORS)
    if not any(fitted(f"ir{i}_gain") for i in sensors):
        return (), ()
    gains, noise = [], []
    for i in sensors:
        gain = values[f"ir{i}_gain"] if fitted(f"ir{i}_gain") else 1.0
        counts = DATASHEET_NOISE_COUNTS
        if fitted(f"ir{i}_noise"):
            spread, model = values[f"ir{i}_noise"], float(params[f"ir{i}_noise"]["datasheet"])
            proportional = max(0.0, model**2 - DATASHEET_NOISE_COUNTS**2)
            counts = min(1000.0, math.sqrt(max(0.0, spread**2 - proportional)))
        gains.append(gain)
        noise.append(round(counts, 3))
    return tuple(gains), tuple(noise)
