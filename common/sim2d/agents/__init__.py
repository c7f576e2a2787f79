"""Robot types: one module per type, each exporting ``SPEC`` (an AgentTypeSpec).

Adding a type is adding a module here and a line in ``AGENT_TYPES``; nothing
else in the engine knows robot types by name.
"""

from __future__ import annotations

from common.sim2d.agents import epuck, khepera
from common.sim2d.specs import AgentTypeSpec

AGENT_TYPES: dict[str, AgentTypeSpec] = {
    khepera.SPEC.name: khepera.SPEC,
    epuck.SPEC.name: epuck.SPEC,
}


def agent_type(name: str) -> AgentTypeSpec:
    try:
        return AGENT_TYPES[name]
    except KeyError:
        known = ", ".join(sorted(AGENT_TYPES))
        raise ValueError(f"unknown agent type {name!r} (known: {known})") from None
