"""A real arena's copy in the simulator, from the snapshot of it a run or a world gives.

A dry run rebuilds the arena it will run on (services/runner/dryrun.py); the sensor
gap (common/twin/readings.py) rebuilds the arena a recorded run was on, to read what
a model's sensors would have read along the run's tracked path. Both go through the
map format (common/sim2d/maps.py), so the copy is built by the code every simulated
world is built by.
"""

from __future__ import annotations

import math
from typing import Any

from common.messages import WorldSnapshot
from common.sim2d import maps
from common.sim2d.world import World
from common.twin.twinfile import Twin


def snapshot_to_map(snap: WorldSnapshot) -> dict[str, Any]:
    """The arena of a snapshot as a map (common/sim2d/maps.py format), robots where they are."""

    def shape(info: Any) -> dict[str, Any]:
        if info.shape.kind == "circle":
            return {"shape": "circle", "radius": max(info.shape.radius, 0.1)}
        return {"shape": "polygon", "points": [list(p) for p in info.shape.points]}

    def pose(x: float, y: float, heading: float) -> dict[str, float]:
        return {"x": x, "y": y, "heading_deg": math.degrees(heading)}

    out: dict[str, Any] = {
        "format": maps.FORMAT,
        "version": maps.VERSION,
        "name": snap.world,
        "arena": {"width": snap.width, "height": snap.height},
        "obstacles": [],
        "objects": [],
        "lights": [],
        "agents": [],
    }
    for item in snap.items:
        if item.category == "obstacle":
            out["obstacles"].append(
                {"id": item.id, **shape(item), **pose(item.x, item.y, item.heading)}
            )
        elif item.category == "object":
            out["objects"].append(
                {
                    "id": item.id,
                    "kind": item.kind,
                    **shape(item),
                    **pose(item.x, item.y, item.heading),
                    "mass": max(item.mass, 1.0),
                    "resistivity": item.resistivity,
                }
            )
    for light in snap.lights:
        out["lights"].append(
            {
                "id": light.id,
                "x": light.x,
                "y": light.y,
                "intensity": light.intensity,
                "radius": light.radius,
                "mode": light.mode,
                "period": light.period,
            }
        )
    if snap.robot_files:  # types the lab does not ship: simulated from their files
        out["robot_types"] = dict(snap.robot_files)
    for agent in snap.agents:
        out["agents"].append(
            {
                "id": agent.id,
                "type": agent.type,
                **pose(agent.x, agent.y, agent.heading),
                "gripper": agent.gripper,
            }
        )
    return out


def world_from_snapshot(snap: WorldSnapshot, twin: Twin | None = None) -> World:
    """A private World like the snapshot's (MapError if it cannot be rebuilt); ``twin``'s
    robot simulated by its twin's robot file (the Khepera with the fitted drive)."""
    room = snapshot_to_map(snap)
    if twin is not None:
        room.setdefault("robot_types", {})[twin.type_name] = twin.robot_file()
        for agent in room["agents"]:
            if agent["id"] == twin.robot:
                agent["type"] = twin.type_name
    return maps.build_world(
        room,
        name=snap.world,
        seed=snap.seed,
        tick_s=snap.tick_s,
        source=f"world {snap.world}",
    )


def sensing_world(
    snap: WorldSnapshot, agent: str, type_name: str, robot_file: str, at: tuple[float, ...]
) -> World:
    """The snapshot's arena (walls, obstacles, lights) with ``agent`` alone in it at ``at``
    (x mm, y mm, heading rad: where the camera saw it, so where it fits), of the robot type
    ``robot_file`` describes: what that robot's sensors read anywhere in it
    (MapError: the arena cannot be rebuilt).

    The other robots and the movable objects are left out: they move during a run, and
    the snapshot has them only where they stood at its start.
    """
    room = snapshot_to_map(snap)
    room["objects"] = []
    room["robot_types"] = {**room.get("robot_types", {}), type_name: robot_file}
    start = {"x": at[0], "y": at[1], "heading_deg": math.degrees(at[2])}
    room["agents"] = [{"id": agent, "type": type_name, **start}]
    return maps.build_world(room, name=snap.world, seed=0, source=f"world {snap.world}")
