"""Access-control rules are built from the key builders, and name keys the services use."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import zenoh

from common import dataflow, keys
from common.keys import AliveKind
from services.lab import zsecurity


def _concrete_keys(realm: str) -> list[str]:
    """One real key from every builder, with sample ids (what services put and serve on)."""
    built = []
    sample = {"ctx": "lobby", "world": "arena1", "agent": "k0", "user": "alice"}
    sample |= {
        "runner": "runner",
        "host": "local",
        "ident": "x",
        "camera": "cam",
        "grader": "grader",
        "competition": "final",
        "course": "robotics-26",
    }
    for name, fn in inspect.getmembers(keys, inspect.isfunction):
        if fn.__module__ != keys.__name__ or name.startswith(("_", "check_", "is_", "parse_")):
            continue
        params = [p for p in inspect.signature(fn).parameters if p != "realm"]
        if "realm" not in inspect.signature(fn).parameters or "builder" in params:
            continue
        kinds = list(AliveKind) if "kind" in params else [None]
        for kind in kinds:
            args = {p: sample[p] for p in params if p != "kind"}
            if kind is not None:
                args["kind"] = kind
            built.append(fn(realm=realm, **args))
    return built


def test_every_acl_pattern_names_keys_the_services_build() -> None:
    realm = "lab"
    root = keys.realm_root(realm)
    real = [zenoh.KeyExpr(k) for k in _concrete_keys(realm)]
    unused = []
    for role, grants in zsecurity.ROLE_GRANTS.items():
        for grant in grants:
            for pattern in grant.keys:
                expr = zenoh.KeyExpr(f"{root}/{pattern}")
                if not any(expr.intersects(k) for k in real):
                    unused.append(f"{role} {grant.verb} {pattern}")
    assert not unused, f"ACL patterns no builder makes a key for: {unused}"


def test_wildcard_builds_the_pattern_of_a_builder() -> None:
    assert keys.wildcard(keys.ctx_join) == "ctx/*/join"
    assert keys.wildcard(keys.agent_cmd) == "world/*/agent/*/cmd"
    assert keys.wildcard(keys.alive, kind=AliveKind.USER) == "alive/user/*"
    assert keys.wildcard(keys.alive_all) == "alive/**"


def test_no_key_string_literal_is_left_in_the_dataflow_or_the_acl_module() -> None:
    acl = Path(zsecurity.__file__).read_text()
    for module, source in (
        (zsecurity, acl[acl.index("ROLES = ") : acl.index("def acl_config(")]),
        (dataflow, Path(dataflow.__file__).read_text()),
    ):
        literals = re.findall(r'"([a-z*]+(?:/[a-z*]+)+)"', source)
        assert not literals, f"key patterns written by hand in {module.__name__}: {literals}"


def test_every_key_has_a_role_that_produces_it_and_one_that_consumes_it() -> None:
    """A key no role may put (or serve) is dead in a lab with access control, and one
    no role may read is a leak nobody hears: the grants are the dataflow, checked."""
    realm = "lab"
    root = keys.realm_root(realm)
    produce, consume = {"pub", "serve", "token"}, {"sub", "ask", "watch"}
    # A router's own liveliness token is declared inside the router, which its own
    # access control does not filter; the realm root is a prefix, not a key.
    exempt = {root, keys.alive(realm, AliveKind.ROUTER, "x")}
    dead = []
    for key in _concrete_keys(realm):
        expr = zenoh.KeyExpr(key)
        verbs = {
            grant.verb
            for grants in zsecurity.ROLE_GRANTS.values()
            for grant in grants
            for pattern in grant.keys
            if zenoh.KeyExpr(f"{root}/{pattern}").intersects(expr)
        }
        if key not in exempt and "*" not in key and not (verbs & produce and verbs & consume):
            dead.append(f"{key}: {sorted(verbs) or 'no grant'}")
    assert not dead, "keys without both a producer and a consumer role:\n" + "\n".join(dead)
