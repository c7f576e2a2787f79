"""A world as the page draws it: its layout, its frames, a robot's readings, map edits.

:class:`WorldFeed` is what the page needs of a world (a simulated or a real arena,
live or replayed), as a Protocol; the rest is plain data, numpy arrays for bulk
poses. Units are the world's: millimetres, radians, seconds; x right, y up, the
origin at the arena's lower-left corner (viewers/web/geometry.py converts).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
import numpy.typing as npt

from common.messages.world import RobotTypeReply

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class Obstacle:
    """A wall or box: centre, size, rotation (mm, rad)."""

    ident: str
    x: float
    y: float
    w: float
    h: float
    angle: float = 0.0
    round: bool = False  # a pillar: a disc of diameter w


@dataclass(frozen=True)
class Ball:
    ident: str
    x: float
    y: float
    r: float


@dataclass(frozen=True)
class Light:
    ident: str
    x: float
    y: float
    on: bool = True


@dataclass(frozen=True)
class SceneLayout:
    """The slowly-changing part of a world: the arena and its fixed things.

    ``version`` changes whenever an edit changes any of it, so a view knows to
    redraw; robots' poses travel in :class:`SceneFrame` instead.
    """

    world: str
    width: float  # mm
    height: float  # mm
    obstacles: tuple[Obstacle, ...]
    balls: tuple[Ball, ...]
    lights: tuple[Light, ...]
    robots: tuple[str, ...]  # agent names, in the order of the frame arrays
    robot_radius: float = 27.5  # Khepera I: 55 mm across
    # Each robot's radius (robots order) when they differ: robot files of other sizes
    # in one arena; empty: every robot is robot_radius.
    robot_radii: tuple[float, ...] = ()
    # Lines painted on the floor (points mm, width mm, "#rrggbb"): what floor sensors follow.
    floor_lines: tuple[tuple[tuple[tuple[float, float], ...], float, str], ...] = ()
    # Each robot type's look: (S, 2, 3) segments in metres, robot frame, and (S, 2, 3)
    # colours; the view draws the selected robot with its type's.
    looks: dict[str, tuple[F32, npt.NDArray[np.uint8]]] = field(default_factory=dict)
    version: int = 0
    offline: frozenset[str] = frozenset()  # robots the bridge cannot reach (drawn grey)
    real: bool = False  # real robots behind a Khepera bridge: no edits, no reset
    # Each robot's type and components (name, role), as its world says: what Check
    # validates a controller's calls against (empty: a type written in Python).
    robot_types: dict[str, tuple[str, tuple[tuple[str, str], ...]]] = field(default_factory=dict)


@dataclass(frozen=True)
class SceneFrame:
    """One tick: every robot's pose in packed arrays (index = snapshot.robots order)."""

    seq: int
    t: float
    poses: F32  # (N, 3): x mm, y mm, theta rad
    gripper: npt.NDArray[np.uint8]  # (N,): 0 none/open, 1 closed, 2 holding
    # (N,): LED bits (bit k: LED k lit); empty when the feed does not know them
    leds: npt.NDArray[np.uint8] = field(default_factory=lambda: np.zeros(0, np.uint8))
    ball_xy: F32 = field(default_factory=lambda: np.zeros((0, 2), np.float32))  # (B, 2)
    lights_on: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, np.bool_))


@dataclass(frozen=True)
class RobotReadings:
    """The selected robot's sensors: 8 IR proximity and 8 ambient readings (0..1023), and
    its wheels' speeds as it reads them (left, right in its type's unit; empty: unknown)."""

    agent: str
    t: float
    ir: F32
    ambient: F32
    speeds: F32 = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass(frozen=True)
class MapEdit:
    """One edit of the map; ``op`` says which fields matter (resize: ``w``, ``h`` of the arena)."""

    op: Literal["move", "add", "delete", "resize"]
    kind: Literal["obstacle", "ball", "light", "agent", "arena"]
    ident: str = ""
    x: float = 0.0
    y: float = 0.0
    angle: float = 0.0
    w: float = 0.0
    h: float = 0.0
    robot_type: str = "khepera"  # add agent: the robot type (a name the world has)


class WorldFeed(Protocol):
    """A world, as the viewer watches it.

    ``latest`` must be cheap and never block: phase 2 backs it with a Zenoh
    ring channel that keeps only the newest frame.
    """

    @property
    def world(self) -> str: ...

    def snapshot(self) -> SceneLayout: ...

    def latest(self) -> SceneFrame | None: ...

    def sensors(self, agent: str) -> RobotReadings | None: ...

    def edit(self, edit: MapEdit) -> None:
        """Apply an edit with the user's session; :class:`LabError` if refused."""
        ...

    def maps(self) -> list[str]:
        """The map files the world's engine can load (edit_map)."""
        ...

    def save_map(self, name: str) -> str:
        """Save the world as map ``name``; returns what the engine said."""
        ...

    def load_map(self, name: str) -> str:
        """Replace the world by map ``name``; every view refetches."""
        ...

    def robot_types(self) -> RobotTypeReply:
        """The robot types and component types the world has (the robot builder)."""
        ...

    def robot_file(self, name: str) -> str:
        """A robot type's file, as the world has it."""
        ...

    def save_robot_type(self, text: str) -> tuple[str, str]:
        """Save a robot file to the lab (edit_map): (what the world said, the type's name)."""
        ...
