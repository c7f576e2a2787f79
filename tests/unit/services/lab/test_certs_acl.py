"""The lab CA and the generated Zenoh security config (the ACL is checked live in netns tests)."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest

from services.lab.certs import CertError, init_ca, inspect, issue
from services.lab.zsecurity import ROLE_GRANTS, VERB_MESSAGES, acl_config, host_tls, zenoh_security


def test_ca_and_leaf_certificates(tmp_path: Path) -> None:
    ca = init_ca(tmp_path)
    assert stat.S_IMODE(ca.key.stat().st_mode) == 0o600
    with pytest.raises(CertError, match="already exists"):
        init_ca(tmp_path)
    leaf = issue(tmp_path, "engine", alt_names=["10.0.0.2", "b.lab"], out_dir=tmp_path / "B")
    assert stat.S_IMODE(leaf.key.stat().st_mode) == 0o600
    info = inspect(leaf.cert)
    assert info.common_name == "engine"
    assert {"10.0.0.2", "b.lab", "localhost", "127.0.0.1"} <= set(info.alt_names)
    assert info.days_left() > 300
    again = issue(tmp_path, "engine", out_dir=tmp_path / "B")  # a rotation: new key, new cert
    assert again.key.read_bytes() != b"" and inspect(again.cert).common_name == "engine"
    with pytest.raises(CertError, match="not valid"):
        issue(tmp_path, "bad name")
    with pytest.raises(CertError, match="no CA"):
        issue(tmp_path / "nowhere", "engine")


def test_only_engines_and_bridges_publish_frames_and_only_agents_publish_leases() -> None:
    def publishers(key: str) -> set[str]:
        return {
            role
            for role, grants in ROLE_GRANTS.items()
            for g in grants
            if g.verb == "pub" and key in g.keys
        }

    assert publishers("world/*/frame") == {"engine", "bridge"}
    assert publishers("world/*/agent/*/sensors") == {"engine", "bridge"}
    assert publishers("world/*/agent/*/lease") == {"agent"}
    # Tracked poses and a camera's words come from the camera's certificate alone.
    assert publishers("world/*/tracked") == {"camera"}
    assert publishers("world/*/camera/*/status") == {"camera"}
    assert publishers("world/*/camera/*/floor") == {"camera"}
    assert "student" not in {r for r, gs in ROLE_GRANTS.items() for g in gs if g.verb == "serve"}


def test_acl_config_has_the_three_lists_and_default_deny() -> None:
    acl = acl_config("lab", {"student": ("student", "guest")})
    assert acl["default_permission"] == "deny"
    rule_ids = {r["id"] for r in acl["rules"]}
    subject_ids = {s["id"] for s in acl["subjects"]}
    for policy in acl["policies"]:
        assert set(policy["rules"]) <= rule_ids
        assert set(policy["subjects"]) <= subject_ids
    students = next(s for s in acl["subjects"] if s["id"] == "students")
    assert students["cert_common_names"] == ["guest", "student"]
    messages = {m for r in acl["rules"] for m in r["messages"]}
    assert messages <= {m for f in VERB_MESSAGES.values() for ms in f.values() for m in ms}
    assert all(
        k.startswith(("wart/lab/", "**", "@/")) for r in acl["rules"] for k in r["key_exprs"]
    )


def test_security_config_needs_its_files(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="wart certs lab"):
        zenoh_security(host_tls(tmp_path, "A", "router"), lease_ms=1000)
    init_ca(tmp_path)
    issue(tmp_path, "router", out_dir=tmp_path / "A")
    conf = zenoh_security(host_tls(tmp_path, "A", "router"), lease_ms=1000)
    tls = conf["transport"]["link"]["tls"]
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert conf["transport"]["link"]["tx"]["lease"] == 1000


def test_whoever_may_read_a_robots_sensors_may_say_it_watches_them() -> None:
    # A world past --streams-up-front publishes a robot's samples only once a
    # watch token is seen: a role that may subscribe to them but not declare
    # that token would wait for samples that never come.
    def roles(verb: str, key: str) -> set[str]:
        return {r for r, gs in ROLE_GRANTS.items() for g in gs if g.verb == verb and key in g.keys}

    readers = roles("sub", "world/*/agent/*/sensors")
    assert readers and readers <= roles("token", "world/*/agent/*/watch")
    assert roles("watch", "world/*/agent/*/watch") == {"engine", "bridge"}
