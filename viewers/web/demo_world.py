"""The demo lab's world: robots circling their home spots, frames on a thread of its own.

Split from viewers/web/demo_lab.py (the labs and connections), which hands
these out; the phase-1 tests and bench/bench_viewer.py also build one alone.
"""

from __future__ import annotations

import itertools
import math
import threading
import time
from dataclasses import replace

import numpy as np

from common.keys import is_ident
from common.messages import RobotTypeReply
from common.robots import registry
from common.world import world_service
from viewers.web.adapters import LabError
from viewers.web.world_feed import (
    Ball,
    Light,
    MapEdit,
    Obstacle,
    RobotReadings,
    SceneFrame,
    SceneLayout,
)


class DemoWorld:
    """A world whose robots circle their home spots; frames at ``rate`` Hz on a thread."""

    def __init__(
        self,
        world: str = "arena",
        robots: int = 8,
        *,
        width: float = 2000.0,
        height: float = 2000.0,
        rate: float = 50.0,
        start: bool = True,
    ) -> None:
        self._world = world
        self.rate = rate
        names = tuple(f"k{i}" for i in range(robots))
        cols = max(1, math.ceil(math.sqrt(robots)))
        rows = max(1, math.ceil(robots / cols))
        ix = np.arange(robots) % cols
        iy = np.arange(robots) // cols
        self._home = np.stack(
            [(ix + 0.5) * width / cols, (iy + 0.5) * height / rows], axis=1
        ).astype(np.float64)
        self._radius = 0.3 * min(width / cols, height / rows)
        self._phase = np.linspace(0, 2 * math.pi, robots, endpoint=False)
        wall = 20.0
        self._snapshot = SceneLayout(
            world=world,
            width=width,
            height=height,
            obstacles=(
                Obstacle("wall_s", width / 2, wall / 2, width, wall),
                Obstacle("wall_n", width / 2, height - wall / 2, width, wall),
                Obstacle("wall_w", wall / 2, height / 2, wall, height),
                Obstacle("wall_e", width - wall / 2, height / 2, wall, height),
                Obstacle("box1", width * 0.3, height * 0.6, 200.0, 100.0, 0.3),
            ),
            balls=(Ball("ball1", width * 0.7, height * 0.3, 30.0),),
            lights=(Light("light1", width * 0.8, height * 0.8, True),),
            robots=names,
        )
        self._lock = threading.Lock()
        self._latest: SceneFrame | None = None
        self._seq = itertools.count()
        self._t0 = time.monotonic()
        self.edits: list[MapEdit] = []
        self.saved: dict[str, SceneLayout] = {}
        self.refuse_edits = ""  # set to a reason to make edit() fail
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.produce()
        if start:
            self.start()

    @property
    def world(self) -> str:
        return self._world

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"fake-{self._world}", daemon=True
            )
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def _run(self) -> None:
        period = 1.0 / self.rate
        next_at = time.monotonic()
        while not self._stop.is_set():
            self.produce()
            next_at += period
            delay = next_at - time.monotonic()
            if delay < -period:  # fell behind: skip rather than burst
                next_at = time.monotonic()
            self._stop.wait(max(0.0, delay))

    def produce(self, t: float | None = None) -> SceneFrame:
        """Compute the frame at time ``t`` (default: now) and make it the latest."""
        t = time.monotonic() - self._t0 if t is None else t
        angle = 0.5 * t + self._phase
        poses = np.empty((len(self._phase), 3), np.float32)
        poses[:, 0] = self._home[:, 0] + self._radius * np.cos(angle)
        poses[:, 1] = self._home[:, 1] + self._radius * np.sin(angle)
        poses[:, 2] = angle + math.pi / 2  # heading along the circle
        gripper = (np.arange(len(poses)) % 3).astype(np.uint8)
        leds = ((np.arange(len(poses)) + int(t)) % 4 == 0).astype(np.uint8)  # one in 4, 1 s each
        snap = self._snapshot
        frame = SceneFrame(
            seq=next(self._seq),
            t=t,
            poses=poses,
            gripper=gripper,
            leds=leds,
            ball_xy=np.array([[b.x, b.y] for b in snap.balls], np.float32).reshape(-1, 2),
            lights_on=np.array([lt.on for lt in snap.lights], np.bool_),
        )
        self._latest = frame  # one reference swap: readers never see half a frame
        return frame

    def snapshot(self) -> SceneLayout:
        return self._snapshot

    def latest(self) -> SceneFrame | None:
        return self._latest

    def sensors(self, agent: str) -> RobotReadings | None:
        if agent not in self._snapshot.robots:
            return None
        t = time.monotonic() - self._t0
        k = np.arange(8, dtype=np.float32)
        ir = 512 + 500 * np.sin(t * 2 + k)
        ambient = 400 + 300 * np.cos(t + k / 2)
        return RobotReadings(agent, t, ir.astype(np.float32), ambient.astype(np.float32))

    def edit(self, edit: MapEdit) -> None:
        if self.refuse_edits:
            raise LabError(self.refuse_edits)
        with self._lock:
            snap = self._snapshot
            self.edits.append(edit)
            if edit.kind == "obstacle":
                obstacles = list(snap.obstacles)
                if edit.op == "add":
                    ident = edit.ident or f"box{len(obstacles)}"
                    obstacles.append(Obstacle(ident, edit.x, edit.y, edit.w or 100, edit.h or 100))
                elif edit.op == "delete":
                    obstacles = [o for o in obstacles if o.ident != edit.ident]
                elif edit.op == "move":
                    obstacles = [
                        replace(o, x=edit.x, y=edit.y, angle=edit.angle)
                        if o.ident == edit.ident
                        else o
                        for o in obstacles
                    ]
                snap = replace(snap, obstacles=tuple(obstacles))
            elif edit.kind == "arena" and edit.op == "resize":
                if edit.w <= 0 or edit.h <= 0:
                    raise LabError("the arena's width and height must be positive")
                snap = replace(snap, width=edit.w, height=edit.h)
            elif edit.op == "delete":
                snap = replace(
                    snap,
                    balls=tuple(b for b in snap.balls if b.ident != edit.ident),
                    lights=tuple(lt for lt in snap.lights if lt.ident != edit.ident),
                )
            elif edit.kind == "light" and edit.op == "add":
                ident = edit.ident or f"light{len(snap.lights) + 1}"
                snap = replace(snap, lights=(*snap.lights, Light(ident, edit.x, edit.y)))
            elif edit.kind == "ball" and edit.op == "add":
                ident = edit.ident or f"ball{len(snap.balls) + 1}"
                snap = replace(snap, balls=(*snap.balls, Ball(ident, edit.x, edit.y, 30.0)))
            self._snapshot = replace(snap, version=snap.version + 1)

    def maps(self) -> list[str]:
        if self.refuse_edits:
            raise LabError(self.refuse_edits)
        return sorted(self.saved)

    def save_map(self, name: str) -> str:
        if self.refuse_edits:
            raise LabError(self.refuse_edits)
        if not is_ident(name):
            raise LabError(f"{name!r} is not a map name: letters, digits, '_', '-', '.'")
        self.saved[name] = self._snapshot
        return f"saved {name}.json"

    def robot_types(self) -> RobotTypeReply:
        return world_service.robot_types(registry.default())

    def robot_file(self, name: str) -> str:
        text = registry.default().texts.get(name)
        if text is None:
            raise LabError(f"no robot type {name!r}")
        return text

    def save_robot_type(self, text: str) -> tuple[str, str]:
        raise LabError("the demo lab keeps no robot types: save them in a real lab")

    def load_map(self, name: str) -> str:
        if self.refuse_edits:
            raise LabError(self.refuse_edits)
        snap = self.saved.get(name)
        if snap is None:
            raise LabError(f"no map named {name}")
        with self._lock:
            self._snapshot = replace(snap, version=self._snapshot.version + 1)
        return f"loaded {name}.json"
