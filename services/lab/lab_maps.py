"""The maps a lab's processes start with: the shipped ones, found by name, and copies of them.

Kept apart from wiring.py (command lines) so both it and the lab's commands can use
them without the rest.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from common import keys

SHIPPED_MAPS = Path(__file__).resolve().parents[2] / "maps"

# Where an emulated Khepera's robot starts when its map names none (the bridge's
# odometry must start where the emulated body is, or the two views disagree).
DEFAULT_POSE = (500.0, 500.0, 0.0)


def find_map(name: str, directories: Sequence[Path]) -> Path:
    """``NAME.json`` in the first directory that has it; the name is one key chunk, not a path."""
    keys.check_ident("map", name)
    stem = name[:-5] if name.endswith(".json") else name
    for directory in directories:
        candidate = directory / f"{stem}.json"
        if candidate.is_file():
            return candidate
    where = " or ".join(str(d) for d in directories)
    raise FileNotFoundError(f"map {name!r} not found (looked in {where})")


def map_with_robots(base: Path, robots: int, out: Path) -> Path:
    """A copy of a map whose robots are replaced by ``robots`` Khepera on a grid."""
    data: dict[str, Any] = json.loads(base.read_text())
    width, height = data["arena"]["width"], data["arena"]["height"]
    data.pop("agents", None)
    data["agent_groups"] = [
        {
            "type": "khepera",
            "count": robots,
            "prefix": "k",
            "area": [100, 100, width - 100, height - 100],
            "spacing": 90,
            "gripper": False,
        }
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1))
    return out


def map_pose(map_path: Path) -> tuple[float, float, float]:
    """Where the map's first robot stands (x mm, y mm, heading degrees)."""
    data: dict[str, Any] = json.loads(map_path.read_text())
    for agent in data.get("agents", []):
        return (
            float(agent.get("x", DEFAULT_POSE[0])),
            float(agent.get("y", DEFAULT_POSE[1])),
            float(agent.get("heading_deg", DEFAULT_POSE[2])),
        )
    return DEFAULT_POSE
