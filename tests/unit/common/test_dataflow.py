"""The dataflow table (common/dataflow.py) is the one place the lab's keys are described.

What it derives (the routers' grants, each put's QoS, the architecture's key
table) must follow it, and what it omits must be a deliberate omission.
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import zenoh

from common import dataflow, dataflow_doc, keys, qos
from common.messages import all_message_types
from services.lab import zsecurity

REPO = Path(__file__).resolve().parents[3]

# Wire types that never travel alone: each rides inside one that the table names.
NESTED = {
    "AuthEnvelope": "wraps every sealed message",
    "AuditEntry": "rows of AuditList",
    "BanInfo": "rows of UserList",
    "ThrottleInfo": "rows of ThrottleList",
    "ChatLine": "inside RoomEvent and JoinReply",
    "ClassTable": "inside ClassTables",
    "KeyCredential": "inside LoginRequest",
    "LoginRequest": "sealed into SealedLogin",
    "LoginVouch": "rides with a browser user's login",
    "MemberStatus": "inside RoomEvent and JoinReply",
    "PasswordCredential": "inside LoginRequest",
    "ResumeCredential": "inside LoginRequest",
    "ResumeGrant": "inside LoginReply",
    "Revocation": "inside RevocationList",
    "RevocationList": "signed into SignedRevocations",
    "RunClaim": "sealed into RunAccepted",
    "SessionToken": "signed into SignedToken",
    "SignedResume": "inside LoginReply and ResumeCredential",
    "SignedToken": "inside LoginReply and AuthEnvelope",
    "UserInfo": "rows of UserList and DirectoryReply",
}


def _builders() -> dict[str, dataflow.KeyBuilder]:
    skip = ("_", "check_", "is_", "parse_", "wildcard", "realm_")
    return {
        name: fn
        for name, fn in inspect.getmembers(keys, inspect.isfunction)
        if fn.__module__ == keys.__name__
        and not name.startswith(skip)
        and "realm" in inspect.signature(fn).parameters
    }


def _aggregate(name: str) -> bool:
    """A builder of a wildcard key some process subscribes to or asks (``*_all``)."""
    return name.endswith("_all") or name == "alive_of_kind"


def test_every_key_the_lab_builds_is_in_the_table() -> None:
    in_table = {flow.key for flow in dataflow.FLOWS}
    missing = [
        name for name, fn in _builders().items() if not _aggregate(name) and fn not in in_table
    ]
    assert not missing, f"key builders with no flow in common/dataflow.py: {missing}"


def test_every_wildcard_a_process_uses_covers_keys_of_the_table() -> None:
    root = keys.realm_root("r")
    patterns = [zenoh.KeyExpr(f"{root}/{flow.pattern_key()}") for flow in dataflow.FLOWS]
    stray = []
    for name, fn in _builders().items():
        if not _aggregate(name):
            continue
        ids = {p: "x" for p in inspect.signature(fn).parameters if p not in ("realm", "kind")}
        if "kind" in inspect.signature(fn).parameters:
            ids["kind"] = keys.AliveKind.USER
        built = fn(realm="r", **ids)
        if not any(p.intersects(zenoh.KeyExpr(built)) for p in patterns):
            stray.append(f"{name} ({built})")
    assert not stray, f"wildcards that meet no flow of the table: {stray}"


def test_every_wire_message_travels_on_a_key_or_inside_one_that_does() -> None:
    carried = {ex.message for flow in dataflow.FLOWS for ex in flow.exchanges}
    carried |= {r for flow in dataflow.FLOWS for ex in flow.exchanges for r in ex.replies}
    names = {t.__name__ for t in carried if t is not None}
    lost = sorted(t.__name__ for t in all_message_types() if t.__name__ not in names | set(NESTED))
    assert not lost, f"message types on no key of common/dataflow.py: {lost}"
    stale = sorted(set(NESTED) & names)
    assert not stale, f"listed as nested here but the table carries them: {stale}"


def _sources() -> str:
    return "\n".join(
        path.read_text()
        for folder in ("common", "services", "viewers")
        for path in (REPO / folder).rglob("*.py")
    )


def test_each_urgent_put_is_made_with_the_tables_qos_and_only_there() -> None:
    """A WORDS or STOP flow whose publisher never asks qos.of() would travel with the frames."""
    source = _sources()
    used = set(re.findall(r"qos\.of\((?:keys\.)?(\w+)\)", source))
    urgent = {
        flow.key.__name__
        for flow in dataflow.FLOWS
        if flow.pattern is dataflow.Pattern.PUT and flow.urgency is not dataflow.Urgency.FRAMES
    }
    assert urgent - used == set(), f"urgent flows put without qos.of(): {urgent - used}"
    assert used - urgent == set(), f"qos.of() on keys the table leaves at FRAMES: {used - urgent}"


def test_qos_follows_the_urgency() -> None:
    words = qos.of(keys.ctx_events)
    assert words["priority"] == zenoh.Priority.DATA_HIGH
    assert words["congestion_control"] == zenoh.CongestionControl.BLOCK
    stop = qos.of(keys.world_estop)
    assert stop["priority"] == zenoh.Priority.REAL_TIME and stop["express"] is True
    assert qos.of(keys.world_frame) == {}


def test_the_routers_grants_are_the_tables_producers_and_consumers() -> None:
    for role, grants in zsecurity.ROLE_GRANTS.items():
        granted = {(g.verb, k) for g in grants for k in g.keys}
        assert granted == set(dataflow.role_verbs(role)), role
    # Spot checks a reader of the table would make by eye.
    frames = dataflow.flows_of(keys.world_frame)[0]
    assert set(frames.producers) == {"engine", "bridge"}
    lease = dataflow.flows_of(keys.agent_lease)[0]
    assert lease.producers == ("agent",)


def test_every_role_the_table_names_is_a_role_of_the_routers() -> None:
    named = {r for f in dataflow.FLOWS for r in (*f.producers, *f.consumers)}
    assert named <= set(dataflow.ROLES)


def test_the_architecture_carries_the_tables_own_words() -> None:
    doc = (REPO / "docs" / "ARCHITECTURE.md").read_text()
    assert dataflow_doc.markdown_table() in doc, "paste `python -m common.dataflow_doc`'s table"
    assert dataflow_doc.markdown_messages() in doc, "paste `python -m common.dataflow_doc`'s list"
