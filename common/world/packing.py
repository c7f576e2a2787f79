"""Packing the world into its wire types: frames, sensor samples and batches, snapshots.

(Named for what it does beside services/lab/wiring.py, which wires a lab's processes.)
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from common.messages import (
    FINGERS_HOLDING,
    AgentInfo,
    AgentStates,
    FloorLineInfo,
    GripperReading,
    ItemInfo,
    LightInfo,
    PackedArray,
    RobotLook,
    SensorBatch,
    SensorSample,
    ShapeInfo,
    WorldFrame,
    WorldSnapshot,
)
from common.robots import registry as robot_registry
from common.sim2d.collision import CAT_ROBOT
from common.sim2d.entities import Agent, Obstacle, ShapeSpec, Zone
from common.sim2d.map_robots import carried_files
from common.sim2d.parts import parts_of
from common.sim2d.world import World

_FINGERS = ("open", "closed", "holding")


def rows(world: World) -> list[str]:
    """The row order of WorldFrame.poses: agents, then movable objects."""
    return [a.id for a in world.agents] + [o.id for o in world.objects]


def frame(world: World) -> WorldFrame:
    poses = np.concatenate([world.agent_pose, world.object_pose]).astype(np.float32)
    n = len(world.agents)
    leds = np.zeros(n, dtype=np.uint8)
    fingers = np.asarray(world.fingers, dtype=np.uint8).copy()
    if n:
        # Per-robot work in numpy only: at 10,000 robots a Python loop over the
        # agents (who holds what) and the LEDs' shifts and sum took 1.2 of the
        # frame's 1.6 ms, every tick.
        lit = world.leds
        if lit.shape[1] <= 8:
            leds = np.packbits(lit != 0, axis=1, bitorder="little")[:, 0]
        else:
            bits = (lit.astype(np.uint16) << np.arange(lit.shape[1], dtype=np.uint16)).sum(1)
            leds = np.minimum(bits, 255).astype(np.uint8)
        fingers[world.holding()] = FINGERS_HOLDING
    states = AgentStates(
        leds=leds,
        arm=np.clip(world.arm, 0, 255),
        fingers=fingers,
        presence=np.clip(world.presence, 0, 255),
    )
    return WorldFrame(
        world=world.name,
        tick=world.tick,
        sim_time=world.sim_time,
        layout=world.layout,
        poses=PackedArray.from_numpy(poses.reshape(-1, 3)),
        agent_state=states.pack(),
        lights=PackedArray.from_numpy(world.lights_on().astype(np.uint8)),
    )


def sample(world: World, slot: int) -> SensorSample:
    return samples(world, [slot])[0]


def samples(world: World, slots: list[int]) -> list[SensorSample]:
    """The SensorSample of each agent in ``slots``, at this tick.

    Built from the world's arrays converted to Python lists once for all of
    them: the engine publishes every driven agent's sample each tick, and
    per-element numpy access cost more than the message itself.
    """
    if not slots:
        return []
    proximity = world.proximity.tolist()
    ambient = world.ambient.tolist()
    counters = world.counters.tolist()
    speeds = world.cmd.tolist()
    leds = world.leds.tolist()
    arm = np.clip(np.rint(world.arm), 0, 255).astype(np.int64).tolist()
    presence = world.presence.tolist()
    name, tick, sim_time = world.name, world.tick, world.sim_time
    parts = parts_of(world, slots)  # [{}...] at once for robots without batched sensors
    out = []
    for i, slot in enumerate(slots):
        agent = world.agents[slot]
        spec = agent.spec
        gripper = None
        if agent.has_gripper:
            gripper = GripperReading(
                arm=arm[slot],
                fingers=_FINGERS[world.gripper_state(slot)],  # type: ignore[arg-type]
                presence=int(presence[slot]),
                resistivity=world.resistivity(slot),
            )
        c, v = counters[slot], speeds[slot]
        out.append(
            SensorSample(
                world=name,
                agent=agent.id,
                tick=tick,
                sim_time=sim_time,
                proximity=proximity[slot][: len(spec.proximity.poses)],
                ambient=ambient[slot][: len(spec.ambient.poses)],
                counters=(int(c[0]), int(c[1])),
                speeds=(int(v[0]), int(v[1])),
                leds=leds[slot][: spec.leds],
                gripper=gripper,
                parts=parts[i],
            )
        )
    return out


def batch(world: World) -> SensorBatch:
    return SensorBatch(
        world=world.name,
        tick=world.tick,
        sim_time=world.sim_time,
        layout=world.layout,
        proximity=PackedArray.from_numpy(world.proximity.astype(np.uint16)),
        ambient=PackedArray.from_numpy(world.ambient.astype(np.uint16)),
        counters=PackedArray.from_numpy(world.counters.astype(np.int64).astype(np.int32)),
    )


def _shape(shape: ShapeSpec) -> ShapeInfo:
    if shape.kind == "circle":
        return ShapeInfo(kind="circle", radius=shape.radius_mm)
    return ShapeInfo(kind="polygon", points=[(float(x), float(y)) for x, y in shape.vertices()])


def _tongs(world: World, agent: Agent) -> list[tuple[float, float, float, float]]:
    """The agent's tongs, where they collide with robots and walls (AgentInfo.tongs)."""
    grip = agent.spec.gripper
    if not agent.has_gripper or grip is None or not world.tongs_mask & CAT_ROBOT:
        return []
    half = grip.tong_width_mm / 2
    y = grip.gap_mm / 2 + half
    x0, x1 = grip.tong_x_mm
    return [(x0, x1, y, half), (x0, x1, -y, half)]


def looks(world: World) -> list[RobotLook]:
    """Each robot type's look, once per type (its components draw themselves: the viewer
    draws the selected robot with it)."""
    components = robot_registry.default().components
    out: dict[str, RobotLook] = {}
    for agent in world.agents:
        spec = agent.spec
        if spec.name in out or not spec.components or len(out) >= 64:
            continue
        segments: list[tuple[float, float, float, float]] = []
        roles: list[str] = []
        for info in spec.components:
            component = components.get(info.type)
            if component is None or (info.role == "gripper" and not agent.has_gripper):
                continue
            drawn = component.preview(info.values)[: 2048 - len(segments)]
            segments += [tuple(float(v) for v in s) for s in drawn]  # type: ignore[misc]
            roles += [info.role] * len(drawn)
        out[spec.name] = RobotLook(type=spec.name, segments=segments, roles=roles)
    return list(out.values())


def _fixed_item(
    item: Obstacle | Zone, category: Literal["obstacle", "zone"], kind: str
) -> ItemInfo:
    """An obstacle's or a zone's entry: it stays where the map or an edit put it."""
    return ItemInfo(
        id=item.id,
        category=category,
        kind=kind,
        shape=_shape(item.shape),
        x=item.x,
        y=item.y,
        heading=item.heading,
        colour=item.colour,
    )


def snapshot(world: World) -> WorldSnapshot:
    items: list[ItemInfo] = []
    for o in world.obstacles.values():
        kind = "wall" if o.shape.kind == "box" else o.shape.kind
        items.append(_fixed_item(o, "obstacle", kind))
    for i, obj in enumerate(world.objects):
        x, y, h = world.object_pose[i] if i < len(world.object_pose) else world.pose_of(obj.id)
        items.append(
            ItemInfo(
                id=obj.id,
                category="object",
                kind=obj.kind,
                shape=_shape(obj.shape),
                x=float(x),
                y=float(y),
                heading=float(h),
                colour=obj.colour,
                mass=obj.mass_g,
                resistivity=obj.resistivity,
            )
        )
    for z in world.zones.values():
        items.append(_fixed_item(z, "zone", z.kind))
    on = world.lights_on()
    lights = [
        LightInfo(
            id=lt.id,
            x=lt.x,
            y=lt.y,
            intensity=lt.intensity,
            radius=lt.radius_mm,
            mode=lt.mode,
            period=lt.period_s,
            colour=lt.colour,
            on=bool(on[i]),
        )
        for i, lt in enumerate(world.lights)
    ]
    agents = []
    for slot, a in enumerate(world.agents):
        x, y, h = world.agent_pose[slot]
        agents.append(
            AgentInfo(
                id=a.id,
                type=a.spec.name,
                radius=a.spec.radius_mm,
                colour=a.colour,
                x=float(x),
                y=float(y),
                heading=float(h),
                gripper=a.has_gripper,
                leds=a.spec.leds,
                proximity_sensors=[(p.x_mm, p.y_mm, p.heading_rad) for p in a.spec.proximity.poses],
                proximity_max=a.spec.proximity.max_value,
                speed_limit=a.spec.drive.max_speed,
                tongs=_tongs(world, a),
                components=[
                    (c.name, c.role)
                    for c in a.spec.components
                    if c.role != "gripper" or a.has_gripper
                ],
            )
        )
    return WorldSnapshot(
        world=world.name,
        tick=world.tick,
        sim_time=world.sim_time,
        layout=world.layout,
        tick_s=world.tick_s,
        seed=world.seed,
        width=world.width,
        height=world.height,
        items=items,
        lights=lights,
        agents=agents,
        rows=rows(world),
        looks=looks(world),
        robot_files=carried_files(a.spec for a in world.agents),
        floor_lines=[
            FloorLineInfo(points=list(line.points), width=line.width_mm, colour=line.colour)
            for line in (world.floor.lines if world.floor is not None else ())
        ],
    )
