"""Every key builder yields a valid, canonical Zenoh key; bad ids are refused."""

from __future__ import annotations

import inspect

import pytest
import zenoh

from common import keys
from common.keys import AliveKind, BadIdentifier

IDS = {
    "realm": "lab",
    "ctx": "room-1",
    "world": "arena",
    "agent": "k1",
    "user": "alice",
    "runner": "r.1",
    "host": "host_a",
    "kind": AliveKind.CONTEXT,
    "ident": "room-1",
    "camera": "cam-1",
    "grader": "g-1",
    "competition": "final-1",
    "course": "robotics-26",
    "key": "wart/lab/alive/context/room-1",
}


def builders() -> list[tuple[str, object]]:
    found = []
    # unwrap: a cached builder (functools.lru_cache) is a builder too
    for name, fn in inspect.getmembers(keys, lambda f: inspect.isfunction(inspect.unwrap(f))):
        if fn.__module__ != keys.__name__ or name.startswith("_"):
            continue
        if name.startswith(("check_", "is_", "parse_", "wildcard")) or "admin" in name:
            continue  # admin-space keys are Zenoh's own: tested below; wildcard makes patterns
        found.append((name, fn))
    return found


@pytest.mark.parametrize(("name", "fn"), builders(), ids=[n for n, _ in builders()])
def test_builder_yields_canonical_key(name: str, fn) -> None:
    params = inspect.signature(fn).parameters
    key = fn(**{p: IDS[p] for p in params})
    assert key == "wart/lab" or key.startswith("wart/lab/")
    assert str(zenoh.KeyExpr(key)) == key
    assert zenoh.KeyExpr.autocanonize(key) == key


@pytest.mark.parametrize(
    "bad", ["", "a/b", "*", "**", "a*", "$x", "@admin", "-lead", "a b", "x" * 65, "room?", "ro#om"]
)
def test_bad_identifiers_are_refused_with_a_clear_error(bad: str) -> None:
    with pytest.raises(BadIdentifier, match="not a valid name"):
        keys.ctx_events("lab", bad)


def test_wildcards_match_the_concrete_keys() -> None:
    concrete = zenoh.KeyExpr(keys.agent_cmd("lab", "arena", "k7"))
    assert zenoh.KeyExpr(keys.agent_cmd_all("lab", "arena")).intersects(concrete)
    assert zenoh.KeyExpr(keys.realm_all("lab")).includes(concrete)
    assert not zenoh.KeyExpr(keys.realm_all("other")).intersects(concrete)


def test_parse_helpers_round_trip() -> None:
    assert keys.parse_alive("lab", keys.alive("lab", AliveKind.WORLD, "arena")) == (
        AliveKind.WORLD,
        "arena",
    )
    assert keys.parse_alive("lab", "wart/lab/alive/nonsense/x") is None
    assert keys.parse_alive("other", keys.alive("lab", AliveKind.WORLD, "arena")) is None
    assert keys.parse_agent_key("lab", "arena", keys.agent_sensors("lab", "arena", "k3")) == "k3"
    assert keys.parse_agent_key("lab", "arena", keys.world_frame("lab", "arena")) is None


def test_admin_space_keys_are_valid_and_outside_every_realm() -> None:
    for key in (keys.router_admin("7c049dee"), keys.routers_admin_all(), keys.admin_space_all()):
        assert key.startswith("@/") and str(zenoh.KeyExpr(key)) == key
    assert zenoh.KeyExpr(keys.routers_admin_all()).intersects(
        zenoh.KeyExpr(keys.router_admin("7c049dee"))
    )
