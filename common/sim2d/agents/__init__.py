"""Robot types by name: the registry's (common/robots/registry.py), read when asked.

A robot type is a TOML file (common/robots/shipped/khepera.toml, epuck.toml, a
plugin's, a lab's robot directory); the registry compiles each into an
AgentTypeSpec. khepera.py and epuck.py keep the two types as they were written
in Python before the files: the shipped files are tested to compile to them
field for field (tests/unit/common/robots/test_shipped.py).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

from common.sim2d.specs import AgentTypeSpec


class _AgentTypes(Mapping[str, AgentTypeSpec]):
    """A live view of the registry's robot types (built on first use, plugins included)."""

    @staticmethod
    def _robots() -> dict[str, AgentTypeSpec]:
        from common.robots import registry  # the registry imports sim2d: import when asked

        return registry.default().robots

    def __getitem__(self, name: str) -> AgentTypeSpec:
        return self._robots()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._robots())

    def __len__(self) -> int:
        return len(self._robots())


AGENT_TYPES: Mapping[str, AgentTypeSpec] = _AgentTypes()


def agent_type(name: str) -> AgentTypeSpec:
    try:
        return AGENT_TYPES[name]
    except KeyError:
        known = ", ".join(sorted(AGENT_TYPES))
        raise ValueError(f"unknown agent type {name!r} (known: {known})") from None


def world_type(name: str, text: str) -> AgentTypeSpec:
    """A robot file a world carries, compiled for that world alone (ValueError: why not)."""
    from common.robots import registry  # the registry imports sim2d: import when asked

    return registry.default().world_type(name, text)


def travels(spec: AgentTypeSpec) -> bool:
    """Must a world send this type's robot file with its robots (not a type the lab ships)?"""
    from common.robots import registry  # the registry imports sim2d: import when asked

    return registry.default().travels(spec)
