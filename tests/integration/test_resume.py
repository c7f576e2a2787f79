"""Resume tokens through a real registry: a saved login comes back without a password,
and logout, kick, ban and a password change each end it, in words."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from common.client.lab_client import LabClient
from common.lab_errors import NotAllowed, WrongCredentials
from common.messages import ResumeGrant, SignedResume, decode, encode
from common.service import close_session, open_session
from tests.conftest import Procs, Router
from tests.kit.lab import PASSWORD, ProcessLab, registry_lab


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    return registry_lab(router, procs, tmp_path)


@contextmanager
def _client(lab: ProcessLab, presence: bool = False) -> Iterator[LabClient]:
    session = open_session(lab.router.options(), wait=10.0)
    try:
        with LabClient(session, lab.realm, lab.identity.verify_key, presence=presence) as client:
            yield client
    finally:
        close_session(session)


def _saved_login(lab: ProcessLab, user: str) -> bytes:
    """A page that logged in and was then closed (a reload): its token stays good."""
    with _client(lab) as page:
        page.login(user, PASSWORD, resume=True)
        assert page.resume_token is not None
        page.keep_resume = True
        return page.resume_token


def test_a_saved_login_resumes_once_and_a_closed_page_keeps_it(lab: ProcessLab) -> None:
    token = _saved_login(lab, "alice")
    with _client(lab) as page:
        page.resume(token)
        assert page.user == "alice"
        assert page.directory().server_name  # a session like any other
        fresh = page.resume_token
        assert fresh is not None and fresh != token
        page.keep_resume = True
    with _client(lab) as thief, pytest.raises(WrongCredentials, match=r"was revoked .used"):
        thief.resume(token)  # used up: a copy is worth one login at most
    with _client(lab) as page:
        page.resume(fresh)  # the newest one still works
        assert page.user == "alice"


def test_logout_kick_ban_and_a_new_password_each_end_a_saved_login(lab: ProcessLab) -> None:
    # logout (the person's "Log out", not a page closing)
    with _client(lab) as page:
        page.login("alice", PASSWORD, resume=True)
        token = page.resume_token
        assert token is not None
        page.logout()
    with _client(lab) as page, pytest.raises(WrongCredentials, match=r"revoked \(logged out\)"):
        page.resume(token)
    with _client(lab) as admin:
        admin.login("admin", PASSWORD)
        # kick
        token = _saved_login(lab, "bob")
        admin.kick_from_server("bob", "talking in the lab")
        with _client(lab) as page, pytest.raises(WrongCredentials, match="kicked from the server"):
            page.resume(token)
        # a new password
        token = _saved_login(lab, "carol")
        admin.set_password("carol", "a brand new one")
        with _client(lab) as page, pytest.raises(WrongCredentials, match="password was changed"):
            page.resume(token)
        # ban: the token is revoked, and a ban is said as a ban even to a good token
        token = _saved_login(lab, "ida")
        admin.ban("ida", "cheating")
        with _client(lab) as page, pytest.raises(WrongCredentials, match="banned"):
            page.resume(token)
        admin.lift_ban("ida")
        token = _saved_login(lab, "ida")
        admin.ban("ida", "cheating again")
        admin.lift_ban("ida")
        with _client(lab) as page, pytest.raises(WrongCredentials, match="revoked"):
            page.resume(token)  # lifting the ban brings no token back
        with _client(lab) as page:
            page.login("ida", PASSWORD)


def test_a_forged_token_is_refused_in_words(lab: ProcessLab) -> None:
    token = _saved_login(lab, "alice")
    signed = decode(token, SignedResume)
    grant = decode(signed.grant, ResumeGrant)
    later = {f: getattr(grant, f) for f in grant.__struct_fields__}
    later["expires_at"] = grant.expires_at + 30 * 24 * 3600  # a month more, unsigned
    forged = encode(SignedResume(grant=encode(ResumeGrant(**later)), signature=signed.signature))
    with _client(lab) as page, pytest.raises(WrongCredentials) as info:
        page.resume(forged)
    assert "your saved login is not one this lab's registry signed" in str(info.value)
    assert "log in with your password" in str(info.value)
    with _client(lab) as page:
        page.resume(token)  # the real one was not touched by the forgery


def test_a_login_deriving_its_mailbox_key_after_still_gets_its_kept_messages(
    lab: ProcessLab,
) -> None:
    with _client(lab) as first:
        first.login("bob", PASSWORD)  # his mailbox key is known from then on
    with _client(lab) as alice:
        alice.login("alice", PASSWORD)
        assert not alice.send_private("bob", "kept for you")  # bob is offline: kept
        with _client(lab, presence=True) as page:
            page.login("bob", PASSWORD, defer_mailbox=True)
            assert page.pending == []  # not yet: no mailbox key was sent
            got: list[str] = []
            page.on_private = lambda m: got.append(m.text)
            _wait(lambda: alice.send_private("bob", "live"))  # once bob is seen online
            _wait(lambda: "live" in got)  # it opens without the mailbox key
            kept = page.claim_mailbox(PASSWORD)
            assert [m.text for m in kept] == ["kept for you"]
            assert "kept for you" in got
            with pytest.raises(NotAllowed):  # once
                page.claim_mailbox(PASSWORD)
        with _client(lab) as page:  # a resumed session's live messages open too
            page.login("bob", PASSWORD, resume=True)
            token = page.resume_token
            assert token is not None
            page.keep_resume = True
        with _client(lab, presence=True) as page:
            page.resume(token)
            # A resumed session never chooses the key offline mail is sealed to.
            with pytest.raises(NotAllowed, match="only a session that logged in with the pass"):
                page.claim_mailbox("whatever it likes")
            got = []
            page.on_private = lambda m: got.append(m.text)
            _wait(lambda: alice.send_private("bob", "after the reload"))
            _wait(lambda: got == ["after the reload"])


def _wait(condition: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)
