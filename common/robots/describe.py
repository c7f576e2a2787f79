"""The schemas as text: ``wart robots list``/``describe`` and docs/CONTROLLERS.md's API tables.

Everything printed here is read from the component types' declarations, so
the help, the validation and the documentation cannot drift apart.
"""

from __future__ import annotations

from common.controller.robot import RobotApi
from common.robots.registry import BUILT_IN, Registry
from common.robots.schema import ComponentType, show_value
from common.sim2d.specs import AgentTypeSpec

# What every robot handle answers whatever its parts (common/controller/).
COMMON_CALLS = (
    ("time()", "float s", "the robot's clock (simulated seconds in a simulation)"),
    ("sensors()", "tuple of names", "the robot file's batched sensors, by their names"),
    ("has(name)", "bool", "whether the robot has that component"),
    ("read(name)", "Reading", "a sensor's reading by its name in the robot file"),
)


def robot_api(spec: AgentTypeSpec, gripper: bool = True) -> RobotApi:
    """What a controller of this type may call (``gripper``: the gripper is fitted)."""
    return RobotApi.of(
        spec.name,
        ((c.name, c.role) for c in spec.components if c.role != "gripper" or gripper),
    )


def component_text(component: type[ComponentType], origin: str = BUILT_IN) -> str:
    """One component type: its doc, then a row per parameter (name, kind, unit, default, range)."""
    lines = [f"{component.name}  ({component.role}, from {origin})", f"  {component.doc}"]
    if component.params:
        lines.append("  parameters:")
        width = max(len(p.name) for p in component.params)
        for p in component.params:
            unit = f" [{p.unit}]" if p.unit else ""
            rng = f", range {p.range_text()}" if p.range_text() else ""
            lines.append(
                f"    {p.name:<{width}}  {p.kind}{unit}, default {p.default_text()}{rng}: {p.doc}"
            )
    for call in component.api:
        lines.append(f"    call {call.call}: {call.returns}; {call.doc}")
    return "\n".join(lines)


def api_calls(spec: AgentTypeSpec, registry: Registry) -> list[tuple[str, str, str, str]]:
    """(call, returns, what, component) of every call a controller of this type may make."""
    rows: list[tuple[str, str, str, str]] = []
    for info in spec.components:
        component = registry.components.get(info.type)
        if component is None:
            continue
        for call in component.api:
            rows.append(
                (
                    call.call.format(name=info.name),
                    call.returns,
                    call.doc,
                    f"{info.name} ({info.type})",
                )
            )
    return rows


def robot_text(spec: AgentTypeSpec, registry: Registry) -> str:
    """A robot type: each component with its parameters as the file sets them, then its API."""
    origin = registry.describe_origin("wart.agents", spec.name)
    lines = [f"robot type {spec.name}  (from {origin}, file {spec.source or '-'})"]
    for info in spec.components:
        component = registry.components[info.type]
        lines.append(f"  [components.{info.name}] type = {info.type}: {component.doc}")
        for p in component.params:
            unit = f" {p.unit}" if p.unit else ""
            value = show_value(info.values[p.name]) if p.name in info.values else "-"
            lines.append(f"    {p.name} = {value}{unit}  (default {p.default_text()}: {p.doc})")
    lines.append("  controller API:")
    for call, returns, what, part in api_calls(spec, registry):
        lines.append(f"    robot.{call}  -> {returns}  ({part}: {what})")
    for call, returns, what in COMMON_CALLS:
        lines.append(f"    robot.{call}  -> {returns}  ({what})")
    return "\n".join(lines)


def list_text(registry: Registry) -> str:
    lines = ["robot types:"]
    for name, spec in sorted(registry.robots.items()):
        parts = ", ".join(f"{c.name}:{c.type}" for c in spec.components)
        lines.append(f"  {name:<12} {registry.describe_origin('wart.agents', name)}: {parts}")
    lines.append("component types:")
    for name, component in sorted(registry.components.items()):
        origin = registry.describe_origin("wart.components", name)
        lines.append(f"  {name:<20} {component.role:<10} {origin}")
    for group, table in (("engine types", registry.engines), ("context types", registry.contexts)):
        if table:
            lines.append(f"{group}:")
            for name in sorted(table):
                kind = "wart.engines" if group == "engine types" else "wart.contexts"
                lines.append(f"  {name:<20} {registry.describe_origin(kind, name)}")
    if registry.problems:
        lines.append("refused (the lab runs without them):")
        lines.extend(f"  {p}" for p in registry.problems)
    return "\n".join(lines)


def controllers_markdown(registry: Registry, types: tuple[str, ...] = ("khepera", "epuck")) -> str:
    """The API tables of docs/CONTROLLERS.md, one per shipped robot type."""
    out: list[str] = []
    for name in types:
        spec = registry.robots[name]
        out.append(f"#### `{name}` ({spec.source})")
        out.append("")
        out.append("| call | gives / takes | component | what |")
        out.append("| --- | --- | --- | --- |")
        for call, returns, what, part in api_calls(spec, registry):
            out.append(f"| `robot.{call}` | {returns} | {part} | {what} |")
        for call, returns, what in COMMON_CALLS:
            out.append(f"| `robot.{call}` | {returns} | every robot | {what} |")
        out.append("")
    return "\n".join(out)
