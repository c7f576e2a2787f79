"""A stolen saved login is not an account, against a real registry: it cannot set the
password, it gets no more time than its token allowed, and the owner's "Log out", a
new password, a logout everywhere or a ban ends it with every other session."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from common.client.lab_client import LabClient
from common.lab_errors import NotAllowed, WrongCredentials
from common.messages import ResumeGrant, SignedResume, decode
from common.service import close_session, open_session
from tests.conftest import Procs, Router
from tests.kit.lab import PASSWORD, ProcessLab, registry_lab, session_revoked

WEEK = 7 * 24 * 3600.0


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    return registry_lab(router, procs, tmp_path)


@contextmanager
def _client(lab: ProcessLab) -> Iterator[LabClient]:
    session = open_session(lab.router.options(), wait=10.0)
    try:
        with LabClient(session, lab.realm, lab.identity.verify_key) as client:
            yield client
    finally:
        close_session(session)


def _ends(token: bytes) -> float:
    return decode(decode(token, SignedResume).grant, ResumeGrant).expires_at


def test_a_stolen_saved_login_cannot_lock_the_owner_out_nor_outlive_her_logout(
    lab: ProcessLab,
) -> None:
    with _client(lab) as owner, _client(lab) as thief:
        owner.login("alice", PASSWORD, resume=True)
        stolen = owner.resume_token  # a script in the page read it, or a copied disk
        assert stolen is not None
        thief.resume(stolen, ttl=WEEK)
        # No longer than the token allowed, and no longer token minted from it.
        assert thief.session is not None
        assert thief.session.token.expires_at <= _ends(stolen) + 1e-6
        assert thief.resume_token is not None and _ends(thief.resume_token) <= _ends(stolen)
        # The password is not the thief's to set: not without the current one ...
        with pytest.raises(NotAllowed, match="type your current password"):
            thief.set_password("alice", "the thief's password")
        with pytest.raises(NotAllowed, match="current password is wrong"):
            thief.set_password("alice", "the thief's password", current="a guess at it")
        # ... and the owner's "Log out" ends the session resumed from her login, and its token.
        owner.logout()
        assert session_revoked(thief)
        with _client(lab) as again, pytest.raises(WrongCredentials, match="revoked"):
            again.resume(thief.resume_token)
    with _client(lab) as owner:
        owner.login("alice", PASSWORD)  # still her password
        # Her own page just logged in with the password: it may set a new one as it is.
        owner.set_password("alice", "alice's second password")


def test_a_new_password_a_logout_everywhere_and_a_ban_end_every_session(
    lab: ProcessLab,
) -> None:
    with _client(lab) as page, _client(lab) as laptop, _client(lab) as thief:
        page.login("bob", PASSWORD, resume=True)
        assert page.resume_token is not None
        laptop.login("bob", PASSWORD)
        thief.resume(page.resume_token)
        # bob sets a new one from his laptop with the current one: every other session ends.
        laptop.set_password("bob", "bob's new password", current=PASSWORD)
        assert session_revoked(page) and session_revoked(thief)
        assert not session_revoked(laptop)  # the one that set it knows it
        assert thief.resume_token is not None
        with _client(lab) as again, pytest.raises(WrongCredentials, match="password was changed"):
            again.resume(thief.resume_token)
    with _client(lab) as page, _client(lab) as thief:
        page.login("carol", PASSWORD, resume=True)
        assert page.resume_token is not None
        thief.resume(page.resume_token)
        with _client(lab) as phone:
            phone.login("carol", PASSWORD)
            phone.logout(everywhere=True)  # "my laptop was stolen"
        assert session_revoked(page) and session_revoked(thief)
        assert thief.resume_token is not None
        with _client(lab) as again, pytest.raises(WrongCredentials, match="everywhere"):
            again.resume(thief.resume_token)
    with _client(lab) as admin, _client(lab) as ida:
        admin.login("admin", PASSWORD)
        ida.login("ida", PASSWORD, resume=True)
        admin.set_password("ida", "set by the admin")  # an admin's change ends them too
        assert session_revoked(ida)
        with _client(lab) as again:
            again.login("ida", "set by the admin")
            admin.ban("ida", "cheating")
            assert session_revoked(again)
