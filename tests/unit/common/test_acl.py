"""The ACL model and the credential types, without a network."""

from __future__ import annotations

from pathlib import Path

import nacl.signing
import pytest

from common import acl
from common.auth import RegistryIdentity, Verifier, issue_session
from common.messages import OkReply
from services.registry.accounts_db import DbError, RegistryDB


def test_roles_expand_and_scoped_grants_stay_in_their_scope() -> None:
    everywhere, scoped, roles = acl.expand(
        [("", "role:student"), ("ctx/lobby", "kick"), ("agent/arena/k1", "control")]
    )
    assert roles == ["student"] and "chat" in everywhere and "kick" not in everywhere
    assert acl.allowed("kick", everywhere, scoped, "ctx/lobby")
    assert not acl.allowed("kick", everywhere, scoped, "ctx/other")
    assert not acl.allowed("kick", everywhere, scoped)


def test_agent_scope_inherits_its_context_and_restricted_rooms_ignore_global_grants() -> None:
    everywhere, scoped, _ = acl.expand([("", "role:student"), ("ctx/arena", "edit_map")])
    assert acl.allowed("edit_map", everywhere, scoped, "agent/arena/k1")
    assert acl.allowed("chat", everywhere, scoped, "ctx/private")
    assert not acl.allowed("chat", everywhere, scoped, "ctx/private", restricted=True)
    admin, _, _ = acl.expand([("", "role:admin")])
    assert acl.allowed("chat", admin, {}, "ctx/private", restricted=True)


def test_unknown_grants_and_bad_scopes_are_refused_with_the_reason() -> None:
    with pytest.raises(acl.AclError, match="unknown permission 'fly'"):
        acl.check_grant("fly")
    with pytest.raises(acl.AclError, match="unknown role 'wizard'"):
        acl.check_grant("role:wizard")
    with pytest.raises(acl.AclError, match="bad scope"):
        acl.check_scope("ctx/a/b")
    # A grant edited by hand into nonsense never widens access.
    everywhere, _, _ = acl.expand([("", "role:wizard"), ("", "everything")])
    assert everywhere == frozenset()


def test_principal_checks_per_context_grants_from_the_token() -> None:
    identity = RegistryIdentity.generate()
    session = issue_session(identity, "lab", "bob", ["chat"], grants={"ctx/lobby": ["kick"]})
    principal, _ = Verifier(identity.verify_key, "lab").open(
        "k", session.seal("k", OkReply()), OkReply
    )
    assert principal.allowed("kick", "ctx/lobby") and not principal.allowed("kick", "ctx/x")
    with pytest.raises(Exception, match="'kick' permission in ctx/x"):
        principal.require("kick", scope="ctx/x")


def test_password_and_key_credentials(tmp_path: Path) -> None:
    db = RegistryDB(tmp_path / "r.db")
    db.add_user("alice", ["student"], password="long enough")
    key = nacl.signing.SigningKey.generate()
    db.add_user("svc", ["service"], public_key=bytes(key.verify_key))
    assert db.check_credential("alice", "password", "long enough")
    assert not db.check_credential("alice", "password", "long enougH")
    assert not db.check_credential("nobody", "password", "long enough")
    assert not db.check_credential("svc", "password", "")  # key-only account
    assert db.check_credential("svc", "ed25519", bytes(key.verify_key))
    assert not db.check_credential("svc", "ed25519", bytes(32))
    assert not db.check_credential("alice", "telepathy", "x")
    with pytest.raises(DbError, match="at least 8"):
        db.add_user("short", password="1234")
    with pytest.raises(DbError, match="already exists"):
        db.add_user("alice", password="whatever1")


def test_first_start_creates_one_admin(tmp_path: Path) -> None:
    db = RegistryDB(tmp_path / "r.db")
    password = db.ensure_admin()
    assert password and db.check_credential("admin", "password", password)
    assert db.ensure_admin() is None


def test_a_services_account_is_said_in_words_a_persons_as_is() -> None:
    from common.acl import account_in_words
    from viewers.web.adapters import AgentStatus
    from viewers.web.robot_panel import format_agents

    assert account_in_words("runner-runner") == "the runner"
    assert account_in_words("grader-grader") == "the grader"
    assert account_in_words("runner-r2") == "the runner r2"
    assert account_in_words("ctx-arena") == "the context arena"
    assert account_in_words("alice") == "alice" and account_in_words("runner-") == "runner-"
    # The grader's real-robot attempt holds a robot: the table says who in words.
    table = format_agents([AgentStatus("k1", holder="grader-grader", queue=0, slot_left_s=8.0)])
    assert "the grader (8 s left)" in table and "grader-grader" not in table
