"""The robot types a world carries: each type's robot file, travelling with its robots.

A robot type saved in one lab (the page's builder, a robot directory) exists in
the engine that keeps it; a runner's dry run, a graded episode or a map saved
and loaded elsewhere rebuilds the world in another process, which has only the
types the lab ships. So a map (docs/MAPS.md, ``robot_types``) and a world's
snapshot carry the file of every type their robots use that the lab does not
ship, and the process that builds the world compiles them for that world alone
(never into its own registry: one lab's ``scout`` cannot change another's).
A file is compiled when a robot of its type is placed, so a bad one fails the
world that uses it, with the robot and the reason, and nothing else.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from common.keys import is_ident
from common.sim2d.agents import AGENT_TYPES, travels, world_type
from common.sim2d.specs import AgentTypeSpec

MAX_TYPES = 32  # a world of more kinds of robot than this is not a class's arena
MAX_FILE_CHARS = 64 * 1024  # common.robots.robotfile.MAX_BYTES (checked in bytes there)


class RobotTypeError(ValueError):
    """A robot type a world needs cannot be simulated here; ``str()`` is the user's reason."""


class MapRobotTypes:
    """The types a world is built with: the lab's (this process's registry) and the
    robot files its map carries, the latter compiled on first use for this world only."""

    def __init__(self, files: Mapping[str, str] | None = None) -> None:
        self.files = dict(files or {})
        self._compiled: dict[str, AgentTypeSpec] = {}

    @classmethod
    def read(cls, value: Any) -> MapRobotTypes:
        """From a map's ``robot_types`` (an object of type name -> robot file text);
        RobotTypeError naming the problem."""
        if not isinstance(value, dict):
            raise RobotTypeError("robot_types: must be an object {type name: robot file text}")
        if len(value) > MAX_TYPES:
            raise RobotTypeError(f"robot_types: at most {MAX_TYPES} robot types")
        for name, text in value.items():
            if not is_ident(name):
                raise RobotTypeError(f"robot_types: {name!r} is not a robot type's name")
            if not isinstance(text, str) or len(text) > MAX_FILE_CHARS:
                raise RobotTypeError(
                    f"robot_types.{name}: must be a robot file's text "
                    f"(at most {MAX_FILE_CHARS} characters)"
                )
        return cls(value)

    @classmethod
    def of(cls, specs: Iterable[AgentTypeSpec]) -> MapRobotTypes:
        """The types a running world carries (its robots'), each as the very spec its
        robots have: a robot added live shares its type's spec with them."""
        held = list(specs)
        types = cls(carried_files(held))
        types._compiled = {s.name: s for s in held if s.name in types.files}
        return types

    def names(self) -> tuple[str, ...]:
        return tuple(sorted(set(AGENT_TYPES) | set(self.files)))

    def __contains__(self, name: object) -> bool:
        return name in self.files or name in AGENT_TYPES

    def spec(self, name: str, agent: str) -> AgentTypeSpec:
        """The type of robot ``agent``: the map's file of ``name`` if it carries one, else
        the lab's (KeyError); RobotTypeError if the map's file cannot be simulated here."""
        if name not in self.files:
            return AGENT_TYPES[name]
        spec = self._compiled.get(name)
        if spec is None:
            try:
                spec = world_type(name, self.files[name])
            except ValueError as exc:
                raise RobotTypeError(
                    f"robot type {name!r} ({agent}) is not valid here: {exc}"
                ) from None
            self._compiled[name] = spec
        return spec


def carried_files(specs: Iterable[AgentTypeSpec]) -> dict[str, str]:
    """The robot files a world's robots of these types need sent along: every type's the
    lab does not ship, by name; at most MAX_TYPES (a reader refuses more: past them, a
    robot's type is unknown where the world is rebuilt, and only that fails)."""
    out: dict[str, str] = {}
    for spec in specs:
        if spec.name not in out and len(out) < MAX_TYPES and travels(spec):
            out[spec.name] = spec.text
    return out
