"""Where the robots of an emulated arena really are, in a small file the synthetic camera reads.

The Khepera emulator steps a Sim2D world in its own process and writes the
true poses here a few dozen times a second (atomically: a reader never sees
half a file); the synthetic camera renders its frames from them. Only an
emulated arena has a truth: a real one is only seen by its camera.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.files import write_atomic
from common.keys import is_ident

FORMAT = "wart-arena-truth"
VERSION = 1
MAX_BYTES = 64 * 1024


class TruthError(ValueError):
    """A truth file that is missing or wrong; the message says which."""


@dataclass(frozen=True)
class ArenaTruth:
    width_mm: float
    height_mm: float
    robots: dict[str, tuple[float, float, float]]  # agent -> x, y (mm), heading (rad)
    at: float  # wall clock when the poses were true

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "width_mm": self.width_mm,
            "height_mm": self.height_mm,
            "robots": {a: list(p) for a, p in self.robots.items()},
            "at": self.at,
        }


def write_truth(path: Path, truth: ArenaTruth) -> None:
    # Rewritten every tick of the emulator (a live feed, not a record): whole for its
    # readers, never synced to disk (worthless after a crash; two syncs a tick load the
    # disk for nothing: 0.6 ms a write against 0.25 here).
    write_atomic(path, json.dumps(truth.to_json()).encode(), durable=False)


def read_truth(path: Path) -> ArenaTruth:
    try:
        raw = Path(path).read_bytes()[: MAX_BYTES + 1]
    except FileNotFoundError:
        raise TruthError(f"{path}: no truth file (is the emulator running with --truth?)") from None
    except OSError as exc:
        raise TruthError(f"{path}: cannot be read ({exc})") from None
    if len(raw) > MAX_BYTES:
        raise TruthError(f"{path}: larger than {MAX_BYTES} bytes")
    try:
        data = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TruthError(f"{path}: not JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != VERSION:
        raise TruthError(
            f'{path}: not an arena truth file ("format": "{FORMAT}", version {VERSION})'
        )
    try:
        width, height, at = float(data["width_mm"]), float(data["height_mm"]), float(data["at"])
        robots = {}
        for agent, pose in dict(data["robots"]).items():
            if not is_ident(agent) or len(pose) != 3:
                raise ValueError(f"robot {agent!r}")
            x, y, h = (float(v) for v in pose)
            robots[agent] = (x, y, h)
    except (KeyError, TypeError, ValueError) as exc:
        raise TruthError(f"{path}: a field is missing or wrong ({exc})") from None
    values = [width, height, at, *(v for p in robots.values() for v in p)]
    if not all(math.isfinite(v) for v in values) or width <= 0 or height <= 0:
        raise TruthError(f"{path}: sizes must be positive and every number finite")
    return ArenaTruth(width, height, robots, at)


def now_truth(
    width_mm: float, height_mm: float, robots: dict[str, tuple[float, float, float]]
) -> ArenaTruth:
    return ArenaTruth(width_mm, height_mm, robots, time.time())
