"""The emulated Khepera's true physical parameters: what a real robot differs from its datasheet by.

A real Khepera's wheels grip the floor unevenly, its wheels sit a little wider or
narrower than the datasheet's 53 mm, it obeys a command some milliseconds after it
arrives, and each IR sensor answers with its own gain. The emulated robot
(services/bridge/simbody.py) takes these from a file or the emulator's flags, so
that ``wart calibrate`` can be tested against a ground truth it never reads:

    # body.toml
    wheel_scale = [0.97, 0.985]   # the floor's share of each wheel's turn (1: no slip)
    wheel_base_mm = 55.5          # absent: the robot file's (53 mm)
    latency_s = 0.04              # a command moves the wheels this long after it arrives
    ir_gain = [1.0, 0.9, 1.1, 1.0, 1.0, 0.95, 1.0, 1.0]  # each sensor's reading, scaled
    ir_noise_counts = 3.0         # more noise on each reading (counts, Gaussian)
    seed = 7
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SENSORS = 8


class BodyTruthError(ValueError):
    """A body file that cannot be used: its field and the reason."""


@dataclass(frozen=True)
class BodyTruth:
    wheel_scale: tuple[float, float] = (1.0, 1.0)
    wheel_base_mm: float | None = None
    latency_s: float = 0.0
    ir_gain: tuple[float, ...] = field(default_factory=lambda: (1.0,) * SENSORS)
    ir_noise_counts: float = 0.0
    seed: int = 0

    @classmethod
    def of(cls, data: dict[str, Any], source: str = "body") -> BodyTruth:
        """Checked values from a parsed file (unknown or bad fields named)."""
        known = {"wheel_scale", "wheel_base_mm", "latency_s", "ir_gain", "ir_noise_counts", "seed"}
        problems = [f"{k}: unknown field (one of {', '.join(sorted(known))})"
                    for k in sorted(set(data) - known)]  # fmt: skip

        def number(key: str, low: float, high: float, default: float) -> float:
            value = data.get(key, default)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not (math.isfinite(value) and low <= value <= high)
            ):
                problems.append(f"{key}: a number from {low:g} to {high:g}, not {value!r}")
                return default
            return float(value)

        def numbers(key: str, n: int, low: float, high: float) -> tuple[float, ...]:
            value = data.get(key, [1.0] * n)
            if not isinstance(value, list) or len(value) != n:
                problems.append(f"{key}: a list of {n} numbers")
                return (1.0,) * n
            out = []
            for v in value:
                if isinstance(v, bool) or not isinstance(v, int | float) or not low <= v <= high:
                    problems.append(f"{key}: each from {low:g} to {high:g}, not {v!r}")
                    return (1.0,) * n
                out.append(float(v))
            return tuple(out)

        scale = numbers("wheel_scale", 2, 0.5, 1.5)
        base = data.get("wheel_base_mm")
        wheel_base = None if base is None else number("wheel_base_mm", 30.0, 80.0, 53.0)
        latency = number("latency_s", 0.0, 0.5, 0.0)
        gain = numbers("ir_gain", SENSORS, 0.2, 3.0)
        noise = number("ir_noise_counts", 0.0, 100.0, 0.0)
        seed = data.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool):
            problems.append(f"seed: a whole number, not {seed!r}")
            seed = 0
        if problems:
            raise BodyTruthError(f"{source}: " + "; ".join(problems))
        return cls((scale[0], scale[1]), wheel_base, latency, gain, noise, seed)

    @classmethod
    def read(cls, path: Path) -> BodyTruth:
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise BodyTruthError(f"{path}: cannot read it: {exc.strerror or exc}") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise BodyTruthError(f"{path}: not TOML: {exc}") from None
        return cls.of(data, str(path))

    @classmethod
    def slipping(cls, slip: float) -> BodyTruth:
        """The emulator's ``--slip``: the left wheel slips by ``slip``, the right by half."""
        return cls(wheel_scale=(1.0 - slip, 1.0 - slip / 2))
