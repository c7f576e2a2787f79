"""One registry of component types, robot types, engines and context types.

Filled in three ways, in this order: the built-ins (common/robots/components.py,
common/robots/sensors.py and the shipped robot files in common/robots/shipped/),
then installed packages through entry points (pytest's way of finding its
plugins), then robot files a lab keeps in a directory:

==================  =====================================================
group               an entry point's object
==================  =====================================================
``wart.components`` a ComponentType subclass, or a list of them
``wart.agents``     a robot file: a path or an importlib.resources file
                    (anything with ``read_bytes()``), or a list of them
``wart.engines``    an engine type: any object with ``main(argv)``
``wart.contexts``   a context type: any object with ``main(argv)``
==================  =====================================================

A plugin is code the lab's operator installs; a robot file is data and only
ever names the components registered here. A plugin that fails to import, or
declares a bad schema, or a robot file that is refused, is recorded as a
:class:`PluginProblem` with the reason and logged; the lab runs without it
(``wart doctor`` and ``wart robots list`` report the problems).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib import metadata, resources
from pathlib import Path
from typing import Any

from common.files import write_atomic
from common.robots import components as builtin_components
from common.robots import sensors as builtin_sensors
from common.robots.robotfile import MAX_BYTES, RobotFileError, parse, too_big
from common.robots.schema import ComponentType, SchemaError, check_schema
from common.sim2d.specs import AgentTypeSpec

log = logging.getLogger("wart.robots")

GROUPS = ("wart.components", "wart.agents", "wart.engines", "wart.contexts")
BUILT_IN = "built-in"
ROBOTS_DIR_ENV = "WART_ROBOTS_DIR"


@dataclass(frozen=True)
class PluginProblem:
    """Something the registry refused, and why (what ``wart doctor`` reports)."""

    group: str
    name: str
    origin: str  # the distribution that declared it, or a file
    reason: str

    def __str__(self) -> str:
        return f"{self.group} {self.name} (from {self.origin}): {self.reason}"


@dataclass
class Registry:
    components: dict[str, type[ComponentType]] = field(default_factory=dict)
    robots: dict[str, AgentTypeSpec] = field(default_factory=dict)
    engines: dict[str, Any] = field(default_factory=dict)
    contexts: dict[str, Any] = field(default_factory=dict)
    origins: dict[tuple[str, str], str] = field(default_factory=dict)
    problems: list[PluginProblem] = field(default_factory=list)
    texts: dict[str, str] = field(default_factory=dict)  # each robot type's file
    robots_dir: Path | None = None  # where saved robot types go (save_robot)

    def refuse(self, group: str, name: str, origin: str, reason: str) -> None:
        problem = PluginProblem(group, name, origin, reason)
        self.problems.append(problem)
        log.warning("plugin refused: %s; the lab runs without it", problem)

    def _first(self, group: str, what: str, name: str, label: str, origin: str) -> bool:
        """Whether ``name`` is new in ``group``: its origin is noted. Else it is refused
        (``label``: as the problem names it), saying where the ``what`` of that name came from.
        """
        first = self.origins.get((group, name))
        if first is not None:
            self.refuse(group, label, origin, f"a {what} {name!r} exists already (from {first})")
            return False
        self.origins[(group, name)] = origin
        return True

    def add_component(self, component: Any, origin: str, name: str = "") -> bool:
        label = getattr(component, "name", "") or name or repr(component)
        try:
            check_schema(component)
        except SchemaError as exc:
            self.refuse("wart.components", label, origin, f"bad schema: {exc}")
            return False
        if not self._first("wart.components", "component type", component.name, label, origin):
            return False
        self.components[component.name] = component
        return True

    def add_robot(self, data: bytes, source: str, origin: str) -> AgentTypeSpec | None:
        """Compile a robot file and register its type; None (and a problem) if refused."""
        try:
            spec = parse(data, source, self.components)
        except RobotFileError as exc:
            self.refuse("wart.agents", source, origin, str(exc))
            return None
        if not self._first("wart.agents", "robot type", spec.name, source, origin):
            return None
        self.robots[spec.name] = spec
        self.texts[spec.name] = data.decode("utf-8")
        return spec

    def save_robot(self, data: bytes, in_use: frozenset[str] = frozenset()) -> AgentTypeSpec:
        """Validate a robot file, keep it in the robot directory and register its type.

        RobotFileError (every problem, with lines) or ValueError (no directory, or
        the name of a type the lab ships or a plugin gives: those are not replaced).
        A type saved before under the same name is replaced, unless robots of it
        are in a world (``in_use``): two specs of one name would share its readings.
        """
        if self.robots_dir is None:
            raise ValueError("this world keeps no robot types (its engine has no --robots-dir)")
        spec = parse(data, "robot file", self.components)
        origin = self.origins.get(("wart.agents", spec.name))
        if origin is not None and origin != str(self.robots_dir):
            raise ValueError(
                f"robot type {spec.name!r} is the lab's ({origin}): save yours under another name"
            )
        if spec.name in in_use:
            raise ValueError(
                f"robots of type {spec.name!r} are in the world: remove them, then save it again"
            )
        spec = parse(data, f"{spec.name}.toml", self.components)  # named as its file
        write_atomic(self.robots_dir / f"{spec.name}.toml", data)
        self.robots[spec.name] = spec
        self.origins[("wart.agents", spec.name)] = str(self.robots_dir)
        self.texts[spec.name] = data.decode("utf-8")
        return spec

    def add_robot_dir(self, directory: Path) -> None:
        """Every ``*.toml`` in a lab's robot directory (files users saved: data only)."""
        for path in sorted(directory.glob("*.toml")):
            try:
                size = path.stat().st_size
                if size > MAX_BYTES:  # refused unread
                    self.refuse(
                        "wart.agents", path.name, str(directory), str(too_big(path.name, size))
                    )
                    continue
                data = path.read_bytes()
            except OSError as exc:
                self.refuse("wart.agents", path.name, str(directory), f"cannot read: {exc}")
                continue
            self.add_robot(data, path.name, str(directory))

    def load_entry_points(self, eps: Iterable[metadata.EntryPoint] | None = None) -> None:
        """Components of every plugin first (a plugin's robot may use another's sensor)."""
        found = list(eps) if eps is not None else _entry_points()
        order = {g: i for i, g in enumerate(GROUPS)}
        for ep in sorted(found, key=lambda e: order.get(e.group, 99)):
            origin = _origin(ep)
            try:
                obj = ep.load()
            except Exception as exc:  # a plugin's import may raise anything: report it
                self.refuse(
                    ep.group, ep.name, origin, f"failed to import: {type(exc).__name__}: {exc}"
                )
                continue
            items = list(obj) if isinstance(obj, list | tuple) else [obj]
            for item in items:
                if ep.group == "wart.components":
                    self.add_component(item, origin, ep.name)
                elif ep.group == "wart.agents":
                    self._add_robot_object(item, ep.name, origin)
                else:
                    table = self.engines if ep.group == "wart.engines" else self.contexts
                    if not callable(getattr(item, "main", None)):
                        self.refuse(ep.group, ep.name, origin, "has no main(argv)")
                    elif ep.name in table:
                        self.refuse(ep.group, ep.name, origin, f"{ep.name!r} exists already")
                    else:
                        table[ep.name] = item
                        self.origins[(ep.group, ep.name)] = origin

    def _add_robot_object(self, item: Any, name: str, origin: str) -> None:
        try:
            if isinstance(item, str | os.PathLike):
                path = Path(item)
                data, source = path.read_bytes(), path.name
            elif callable(getattr(item, "read_bytes", None)):
                data, source = item.read_bytes(), str(getattr(item, "name", name))
            else:
                self.refuse("wart.agents", name, origin, f"{item!r} is not a robot file")
                return
        except OSError as exc:
            self.refuse("wart.agents", name, origin, f"cannot read its robot file: {exc}")
            return
        self.add_robot(data, source, origin)

    def world_type(self, name: str, text: str) -> AgentTypeSpec:
        """The type of a robot file a world carries (a map's ``robot_types``), for that
        world alone: compiled against this process's components and never registered
        here, so one lab's file cannot change another's type of the same name.

        ValueError, in a user's words, if it cannot be: a refused file (every problem,
        with its line), a file of another name, or a built-in type redefined.
        """
        origin = self.origins.get(("wart.agents", name))
        if origin == BUILT_IN and text != self.texts.get(name):
            raise ValueError(f"{name!r} is a type the lab ships; a world may not redefine it")
        try:
            spec = parse(text.encode("utf-8"), f"{name}.toml", self.components)
        except RobotFileError as exc:
            raise ValueError("; ".join(str(exc).splitlines())) from None
        if spec.name != name:
            raise ValueError(f"its robot file names it {spec.name!r}")
        return spec

    def travels(self, spec: AgentTypeSpec) -> bool:
        """Must a world send this type's robot file along with its robots? Yes, unless the
        lab ships it (every process has those); a type written in Python has no file."""
        return bool(spec.text) and self.origins.get(("wart.agents", spec.name)) != BUILT_IN

    def describe_origin(self, group: str, name: str) -> str:
        return self.origins.get((group, name), "?")


HOSTED_KINDS = ("number", "integer", "boolean", "text", "choice")


def context_arguments(kind: Any, params: dict[str, str]) -> list[str]:
    """A plugin context type's command line from a request's params, checked by its schema.

    The type declares ``params`` (Params of the kinds above); each value arrives
    as text, is converted and checked like a robot file's, and becomes
    ``--name value``. Unknown, missing or bad params raise ValueError naming
    the param; a text may not start with "-" (it would read as an option).
    """
    schema = {p.name: p for p in getattr(kind, "params", ())}
    out: list[str] = []
    for name in params:
        if name not in schema:
            known = ", ".join(schema) or "none"
            raise ValueError(f"{name}: not a parameter of this context type (it has: {known})")
    for name, p in schema.items():
        if p.kind not in HOSTED_KINDS:
            raise ValueError(f"{name}: a {p.kind} parameter cannot be given on request")
        if name not in params:
            if p.required:
                raise ValueError(f"{name}: is required ({p.doc})")
            continue
        text = params[name]
        value: Any = text
        try:
            if p.kind == "number":
                value = float(text)
            elif p.kind == "integer":
                value = int(text)
            elif p.kind == "boolean":
                if text not in ("true", "false"):
                    raise ValueError
                value = text == "true"
        except ValueError:
            raise ValueError(f"{name}: must be a {p.kind}, got {text!r}") from None
        bad = p.problem(value)
        if bad:
            raise ValueError(f"{name}: {bad}")
        if isinstance(value, str) and value.startswith("-"):
            raise ValueError(f"{name}: may not start with '-'")
        out += [f"--{name.replace('_', '-')}", text]
    return out


def _entry_points() -> list[metadata.EntryPoint]:
    out: list[metadata.EntryPoint] = []
    for group in GROUPS:
        out.extend(metadata.entry_points(group=group))
    return out


def _origin(ep: metadata.EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    if dist is not None:
        return f"{dist.metadata['Name']} {dist.version}"
    return ep.value


def build(plugins: bool = True, robots_dir: Path | None = None) -> Registry:
    """A registry of the built-ins, the installed plugins and a directory of robot files."""
    reg = Registry()
    for component in (*builtin_components.BUILT_IN, *builtin_sensors.BUILT_IN):
        if not reg.add_component(component, BUILT_IN):
            raise SchemaError(str(reg.problems[-1]))  # a built-in's schema is our bug
    shipped = resources.files("common.robots") / "shipped"
    for name in ("khepera.toml", "epuck.toml"):
        if reg.add_robot((shipped / name).read_bytes(), name, BUILT_IN) is None:
            raise RuntimeError(str(reg.problems[-1]))  # a shipped file's problem is our bug
    if plugins:
        reg.load_entry_points()
    directory = robots_dir or (
        Path(os.environ[ROBOTS_DIR_ENV]) if os.environ.get(ROBOTS_DIR_ENV) else None
    )
    if directory is not None:
        reg.robots_dir = directory
        if directory.is_dir():
            reg.add_robot_dir(directory)
    return reg


_DEFAULT: Registry | None = None


def default() -> Registry:
    """The process's registry, built once (the engine and the tools share it)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = build()
    return _DEFAULT


def use(robots_dir: Path | None = None) -> Registry:
    """Build the process's registry now, with this robot directory (the engine's --robots-dir)."""
    global _DEFAULT
    _DEFAULT = build(robots_dir=robots_dir)
    return _DEFAULT


def reset() -> None:
    """Forget the process's registry (tests that install or remove a plugin)."""
    global _DEFAULT
    _DEFAULT = None
