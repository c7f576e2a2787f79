"""The controller API students write against (the thesis's AgentController and KheperaStudent).

A controller is a class deriving from :class:`Controller`::

    from common.controller import Controller, Khepera

    class Avoid(Controller):
        period = 0.05                      # seconds between do_work calls

        def initialize(self, robot: Khepera) -> None:
            robot.set_leds(True, False)

        def do_work(self, robot: Khepera) -> None:
            left, right = robot.proximity().values[2:4]
            robot.set_speeds(10 - right // 100, 10 - left // 100)

        def cleanup(self, robot: Khepera) -> None:
            robot.set_speeds(0, 0)

The same class runs unchanged against a simulated robot or a real one, on the
student's own machine (``wart control``) or uploaded and run in the lab's
sandbox (``wart deploy``). Reads return the newest sample the robot sent and
its time; they never block. Speeds are in the Khepera's units: pulses per
10 ms (about 8 mm/s each), clamped to ±127.

This module uses only the standard library: it is what the sandbox offers.
"""

from __future__ import annotations

import importlib.util
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

from common.controller.robot import check_parts

API_VERSION = 1
"""Raised only when a change would break existing controllers; old ones keep working."""

MAX_SPEED = 127
PROXIMITY_SENSORS = 8
LIGHT_SENSORS = 8
ARM_UP = 165
ARM_DOWN = 255


@dataclass(frozen=True)
class Reading:
    """A sensor reading and the robot-clock time (seconds) it was taken at."""

    values: tuple[int, ...]
    time: float


@dataclass
class KheperaState:
    """The newest state a Khepera reported (as the sandbox and remote links deliver it)."""

    time: float = 0.0
    speeds: tuple[int, int] = (0, 0)
    counters: tuple[int, int] = (0, 0)
    proximity: tuple[int, ...] = (0,) * PROXIMITY_SENSORS
    ambient: tuple[int, ...] = (500,) * LIGHT_SENSORS
    leds: tuple[bool, bool] = (False, False)
    arm: int = ARM_UP
    gripper_closed: bool = False
    object_present: bool = False
    resistivity: int = 0
    # The robot file's batched sensors (floor, range finder, bumper ...) by their names.
    parts: dict[str, tuple[int, ...]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The plain mapping :meth:`from_dict` reads back (the sandbox's pipe carries it)."""
        return {
            "time": self.time,
            "speeds": list(self.speeds),
            "counters": list(self.counters),
            "proximity": list(self.proximity),
            "ambient": list(self.ambient),
            "leds": list(self.leds),
            "arm": self.arm,
            "gripper_closed": self.gripper_closed,
            "object_present": self.object_present,
            "resistivity": self.resistivity,
            **({"parts": {k: list(v) for k, v in self.parts.items()}} if self.parts else {}),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> KheperaState:
        """Build from a plain mapping, checking every field (data crosses a process boundary)."""

        def ints(name: str, count: int, low: int, high: int) -> tuple[int, ...]:
            raw = data.get(name)
            if not isinstance(raw, list | tuple) or len(raw) != count:
                raise ValueError(f"{name}: expected {count} integers")
            out = tuple(int(v) for v in raw)
            if any(not low <= v <= high for v in out):
                raise ValueError(f"{name}: values outside {low}..{high}")
            return out

        t = data.get("time", 0.0)
        if not isinstance(t, int | float):
            raise ValueError("time: expected a number")
        if "arm" in data:
            data = {**data, "arm": [data["arm"]]}
        leds = data.get("leds", [False, False])
        if not isinstance(leds, list | tuple) or len(leds) != 2:
            raise ValueError("leds: expected two booleans")
        return cls(
            time=float(t),
            speeds=ints("speeds", 2, -MAX_SPEED, MAX_SPEED),  # type: ignore[arg-type]
            counters=ints("counters", 2, -(2**31), 2**31 - 1),  # type: ignore[arg-type]
            proximity=ints("proximity", PROXIMITY_SENSORS, 0, 1023),
            ambient=ints("ambient", LIGHT_SENSORS, 0, 1023),
            leds=(bool(leds[0]), bool(leds[1])),
            arm=ints("arm", 1, 0, 255)[0] if "arm" in data else ARM_UP,
            gripper_closed=bool(data.get("gripper_closed", False)),
            object_present=bool(data.get("object_present", False)),
            resistivity=int(data.get("resistivity", 0)),
            parts=check_parts(data.get("parts", {})),
        )


COUNTER_LIMIT = 2**31 - 1
COMMAND_FIELDS = ("speeds", "counters", "leds", "arm", "grip")


@dataclass(frozen=True)
class RobotCommand:
    """One command a controller gives its robot; exactly one field is set.

    The one schema every transport carries: the sandbox's pipe
    (``common.controller.pipe.Command``, its fields as :meth:`to_dict` gives
    them), Zenoh (``common.world.remote_robot`` turns it into an AgentCommand of
    the same field names), and a test's in-process world. Stdlib only, like this
    module, because the sandboxed child imports it.
    """

    speeds: tuple[int, int] | None = None  # pulses per 10 ms, each within ±MAX_SPEED
    counters: tuple[int, int] | None = None  # position counters to set, in pulses
    leds: tuple[bool, bool] | None = None
    arm: int | None = None  # 0..255
    grip: bool | None = None  # True: close the fingers

    def __post_init__(self) -> None:
        # The usual command, 50 times a second per robot: speeds (or counters) alone,
        # two plain ints in range. Accepted here in a few comparisons; anything
        # else takes the full check below, which gives the reason.
        pair = self.speeds if self.counters is None else self.counters
        if (
            type(pair) is tuple
            and self.leds is None
            and self.arm is None
            and self.grip is None
            and (self.speeds is None or self.counters is None)
            and len(pair) == 2
        ):
            a, b = pair
            bound = MAX_SPEED if self.counters is None else COUNTER_LIMIT
            if type(a) is int and type(b) is int and -bound <= a <= bound and -bound <= b <= bound:
                return
        given = [name for name in COMMAND_FIELDS if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(f"a command sets exactly one of {', '.join(COMMAND_FIELDS)}")
        for name, bound in (("speeds", MAX_SPEED), ("counters", COUNTER_LIMIT)):
            value = getattr(self, name)
            if value is not None and (
                not isinstance(value, tuple)
                or len(value) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
                or not all(-bound <= v <= bound for v in value)
            ):
                raise ValueError(f"{name} must be two integers within ±{bound}")
        if self.leds is not None and (
            not isinstance(self.leds, tuple)
            or len(self.leds) != 2
            or not all(isinstance(v, bool) for v in self.leds)
        ):
            raise ValueError("leds must be two booleans")
        if self.arm is not None and (
            not isinstance(self.arm, int) or isinstance(self.arm, bool) or not 0 <= self.arm <= 255
        ):
            raise ValueError("arm must be an integer 0..255")
        if self.grip is not None and not isinstance(self.grip, bool):
            raise ValueError("grip must be true or false")

    def to_dict(self) -> dict[str, Any]:
        """The wire form on the sandbox's pipe: ``{"speeds": [10, -10]}``."""
        for name in COMMAND_FIELDS:
            value = getattr(self, name)
            if value is not None:
                return {name: list(value) if isinstance(value, tuple) else value}
        raise AssertionError("unreachable: __post_init__ requires one field")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobotCommand:
        """A command from its wire form (a ``"t"`` tag is ignored); ValueError if it is not one."""
        if not isinstance(data, dict):
            raise ValueError("a command is a JSON object")
        fields = {k: v for k, v in data.items() if k != "t"}
        unknown = set(fields) - set(COMMAND_FIELDS)
        if unknown:
            raise ValueError(f"unknown command fields: {', '.join(sorted(map(str, unknown)))}")
        if len(fields) != 1:
            raise ValueError(f"a command sets exactly one of {', '.join(COMMAND_FIELDS)}")
        ((name, value),) = fields.items()
        if name in ("speeds", "counters", "leds"):
            if not isinstance(value, list | tuple):
                raise ValueError(f"{name} must be a list of two values")
            value = tuple(value)
        return cls(**{name: value})


class RobotLink(Protocol):
    """What a robot handle needs from its transport (sandbox pipe, Zenoh, a test)."""

    def latest(self) -> KheperaState: ...

    def send(self, command: RobotCommand) -> None: ...


def _clamp_speed(value: float) -> int:
    return max(-MAX_SPEED, min(MAX_SPEED, round(value)))


class Khepera:
    """The control interface of a Khepera (the thesis's KheperaStudent), in Python names.

    Effector calls send a command at once; sensor calls return the newest
    sample and its time.
    """

    def __init__(self, link: RobotLink) -> None:
        self._link = link

    # -- motion

    def set_speeds(self, left: float, right: float) -> None:
        """Wheel speeds in pulses per 10 ms (about 8 mm/s each), clamped to ±127."""
        self._link.send(RobotCommand(speeds=(_clamp_speed(left), _clamp_speed(right))))

    def stop(self) -> None:
        self.set_speeds(0, 0)

    def speeds(self) -> Reading:
        state = self._link.latest()
        return Reading(tuple(state.speeds), state.time)

    def position(self) -> Reading:
        """The wheels' position counters, in pulses (0.08 mm each)."""
        state = self._link.latest()
        return Reading(tuple(state.counters), state.time)

    def set_position(self, left: int, right: int) -> None:
        """Set the position counters (e.g. to zero before measuring a distance)."""
        self._link.send(RobotCommand(counters=(int(left), int(right))))

    # -- sensors

    def proximity(self) -> Reading:
        """8 IR proximity values, 0..1023, larger is closer (about 0 to 50 mm).

        Sensors 0..5 go round the front from left to right, 6 and 7 are at the back.
        """
        state = self._link.latest()
        return Reading(tuple(state.proximity), state.time)

    def ambient(self) -> Reading:
        """8 ambient light values, about 500 in the dark, smaller is brighter."""
        state = self._link.latest()
        return Reading(tuple(state.ambient), state.time)

    def time(self) -> float:
        """The robot's clock (simulated seconds in a simulation)."""
        return self._link.latest().time

    # -- the robot file's own sensors (common/controller/robot.py)

    def sensors(self) -> tuple[str, ...]:
        """The names of this robot's batched sensors, as its robot file names them."""
        return tuple(self._link.latest().parts)

    def has(self, name: str) -> bool:
        """Whether this robot has a sensor of that name (its robot file's components)."""
        return name in self._link.latest().parts

    def read(self, name: str) -> Reading:
        """A sensor's reading by its name in the robot file (``robot.read("floor")``)."""
        state = self._link.latest()
        values = state.parts.get(name)
        if values is None:
            known = ", ".join(state.parts) or "none"
            raise AttributeError(f"this robot has no sensor {name!r} (its sensors: {known})")
        return Reading(values, state.time)

    def __getattr__(self, name: str) -> Callable[[], Reading]:
        # robot.floor() for a [components.floor] sensor: the API follows the robot file.
        if name.startswith("_"):
            raise AttributeError(name)
        if name not in self._link.latest().parts:
            known = ", ".join(self._link.latest().parts) or "none"
            raise AttributeError(
                f"this robot has no {name!r}: not a call of the robot, nor one of its "
                f"sensors ({known})"
            )
        return lambda: self.read(name)

    # -- LEDs

    def set_leds(self, led0: bool, led1: bool) -> None:
        self._link.send(RobotCommand(leds=(bool(led0), bool(led1))))

    # -- gripper turret

    def set_arm(self, position: int) -> None:
        """Arm position 0..255; mechanically about 165 (up) to 255 (down)."""
        self._link.send(RobotCommand(arm=max(0, min(255, int(position)))))

    def arm_up(self) -> None:
        self.set_arm(ARM_UP)

    def arm_down(self) -> None:
        self.set_arm(ARM_DOWN)

    def arm(self) -> int:
        return self._link.latest().arm

    def open_gripper(self) -> None:
        self._link.send(RobotCommand(grip=False))

    def close_gripper(self) -> None:
        self._link.send(RobotCommand(grip=True))

    def gripper_closed(self) -> bool:
        return self._link.latest().gripper_closed

    def object_present(self) -> bool:
        """True when the barrier between the fingers sees an object."""
        return self._link.latest().object_present

    def resistivity(self) -> int:
        """Electrical resistivity of the held object (0 when nothing is held)."""
        return self._link.latest().resistivity


class Controller:
    """Base of every controller: initialize once, do_work every ``period`` s, cleanup once."""

    period: ClassVar[float] = 0.05
    robot_type: ClassVar[str] = "khepera"
    api_version: ClassVar[int] = API_VERSION

    def initialize(self, robot: Khepera) -> None:
        """Called once before the first do_work."""

    def do_work(self, robot: Khepera) -> None:
        """Called every ``period`` seconds while the controller holds the robot."""
        raise NotImplementedError

    def cleanup(self, robot: Khepera) -> None:
        """Called once at the end of the slot (or on stop); the robot is stopped after it."""


@dataclass
class ControllerLoop:
    """Runs a controller at its period until stopped (the thesis's Figure 15 loop).

    ``sleep`` and ``clock`` are injectable so tests need not wait.
    """

    controller: Controller
    robot: Khepera
    stop: threading.Event = field(default_factory=threading.Event)
    clock: Callable[[], float] = time.monotonic
    iterations: int = 0

    def run(self, until: float | None = None) -> None:
        period = float(self.controller.period)
        if not 0.001 <= period <= 10.0:
            raise ValueError(f"period {period} s is outside 0.001..10 s")
        self.controller.initialize(self.robot)
        try:
            next_tick = self.clock()
            while not self.stop.is_set():
                if until is not None and self.clock() >= until:
                    break
                self.controller.do_work(self.robot)
                self.iterations += 1
                next_tick += period
                delay = next_tick - self.clock()
                if delay < 0:  # a slow do_work: start again from now rather than catch up
                    next_tick = self.clock()
                    delay = 0.0
                self.stop.wait(delay)
        finally:
            try:
                self.controller.cleanup(self.robot)
            finally:
                self.robot.stop()


def load_controller(path: str | Path) -> Controller:
    """Import a controller file and instantiate its controller (on the student's own machine).

    The file must define exactly one Controller subclass, or name one with
    ``CONTROLLER = MyController`` (the same rule as the lab's sandbox).
    """
    path = Path(path)
    spec = importlib.util.spec_from_file_location(f"wart_controller_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path} as Python")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    classes = [
        value
        for value in vars(module).values()
        if isinstance(value, type)
        and issubclass(value, Controller)
        and value is not Controller
        and value.__module__ == module.__name__
    ]
    chosen = getattr(module, "CONTROLLER", None) or (classes[0] if len(classes) == 1 else None)
    if chosen is None:
        names = ", ".join(c.__name__ for c in classes) or "none"
        raise TypeError(
            f"{path.name} must define exactly one Controller subclass (found: {names}); "
            "or name one with CONTROLLER = MyController"
        )
    return chosen()
