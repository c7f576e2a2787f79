"""Resume tokens: signed, good once, short-lived, revoked in words."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from common.auth import RegistryIdentity, resume_user
from common.messages import ResumeGrant, SignedResume, decode, encode
from common.service import RequestError
from services.registry import resume
from services.registry.accounts_db import RegistryDB
from services.registry.resume import RESUME_TTL_S, ResumeStore

SID = b"\x07" * 16


@pytest.fixture
def store(tmp_path: Path) -> ResumeStore:
    db = RegistryDB(tmp_path / "registry.db")
    db.add_user("bob", ["student"], public_key=b"\x01" * 32)
    db.add_user("eve", ["student"], public_key=b"\x02" * 32)
    return ResumeStore(db, RegistryIdentity.generate(), "lab")


def test_a_token_names_its_user_is_good_once_and_lasts_no_longer_than_its_session(
    store: ResumeStore,
) -> None:
    now = time.time()
    token = store.issue("bob", SID, now + 12 * 3600, now)
    assert resume_user(token) == "bob"
    grant = store.use("bob", token, now + 1).grant
    assert grant.expires_at == pytest.approx(now + RESUME_TTL_S)
    with pytest.raises(RequestError, match=r"was revoked .used") as info:
        store.use("bob", token, now + 2)
    assert info.value.code == "unauthenticated"
    assert "log in with your password" in info.value.message
    short = store.issue("bob", SID, now + 60, now)  # its session ends in a minute
    with pytest.raises(RequestError, match="expired"):
        store.use("bob", short, now + 61)


def test_forged_altered_and_foreign_tokens_are_refused_in_words(
    store: ResumeStore, tmp_path: Path
) -> None:
    now = time.time()
    token = store.issue("bob", SID, now + 3600, now)
    signed = decode(token, SignedResume)
    grant = decode(signed.grant, ResumeGrant)
    # eve puts her name in bob's grant: the signature no longer holds
    altered = encode(
        SignedResume(
            grant=encode(ResumeGrant(**{**_fields(grant), "user": "eve"})),
            signature=signed.signature,
        )
    )
    with pytest.raises(RequestError, match="is not one this lab's registry signed"):
        store.use("eve", altered, now)
    # signed by another registry
    stranger = ResumeStore(store.db, RegistryIdentity.generate(), "lab")
    other = stranger.issue("bob", SID, now + 60, now)
    with pytest.raises(RequestError, match="is not one this lab's registry signed"):
        store.use("bob", other, now)
    with pytest.raises(RequestError, match="is for another account"):
        store.use("eve", token, now)
    with pytest.raises(RequestError, match="not one this lab's registry signed"):
        store.use("bob", b"junk", now)
    with pytest.raises(ValueError, match="not a resume token"):
        resume_user(b"junk")


def test_logout_kick_and_password_change_revoke_with_their_reason(store: ResumeStore) -> None:
    now = time.time()
    other_sid = b"\x08" * 16
    mine = store.issue("bob", SID, now + 3600, now)
    elsewhere = store.issue("bob", other_sid, now + 3600, now)
    store.revoke_sessions([SID], "logged out")
    with pytest.raises(RequestError, match=r"was revoked \(logged out\)"):
        store.use("bob", mine, now)
    assert store.use("bob", elsewhere, now).grant.user == "bob"  # another session's stays good
    again = store.issue("bob", other_sid, now + 3600, now)
    assert resume.revoke_user(store.db, "bob", "the password was changed") == 1
    with pytest.raises(RequestError, match="the password was changed"):
        store.use("bob", again, now)


def _fields(grant: ResumeGrant) -> dict[str, object]:
    return {f: getattr(grant, f) for f in grant.__struct_fields__}


def test_asking_whether_a_token_is_good_does_not_use_it_and_sees_revocations(
    store: ResumeStore,
) -> None:
    now = time.time()
    token = store.issue("bob", SID, now + 3600, now)
    store.check("bob", SID, token, now + 1)
    store.check("bob", SID, token, now + 2)  # asking twice: still good
    with pytest.raises(RequestError, match="belongs to another session"):
        store.check("bob", b"\x08" * 16, token, now + 3)  # a session asking of another's
    with pytest.raises(RequestError, match="is for another account"):
        store.check("eve", SID, token, now + 3)
    store.revoke_user("bob", "the password was changed")
    with pytest.raises(RequestError, match=r"was revoked \(the password was changed\)"):
        store.check("bob", SID, token, now + 4)
    fresh = store.issue("bob", SID, now + 3600, now)
    store.check("bob", SID, fresh, now + 5)
    store.use("bob", fresh, now + 6)  # the check left it good for one resume
