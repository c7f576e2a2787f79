"""Chat rooms and the registry over a real router, with real processes."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from common import keys
from common.auth import issue_session
from common.lab_errors import NotAllowed, NotFound, RateLimited, RequestFailed
from common.messages import ChatSay, RoomEvent
from tests.conftest import Procs, Router, wait_for
from tests.kit.lab import ProcessLab, make_lab


class Events:
    """Collects a client's room events."""

    def __init__(self) -> None:
        self.items: list[RoomEvent] = []
        self._lock = threading.Lock()

    def __call__(self, event: RoomEvent) -> None:
        with self._lock:
            self.items.append(event)

    def lines(self) -> list[tuple[str, str]]:
        with self._lock:
            return [(e.line.sender, e.line.text) for e in self.items if e.line]

    def statuses(self) -> list[tuple[str, str]]:
        with self._lock:
            return [(e.status.user, e.status.status) for e in self.items if e.status]


# One worker starts the module's router once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    lab.start_room("lobby")
    return lab


def test_two_users_chat_and_a_late_joiner_sees_history(lab: ProcessLab) -> None:
    with lab.client("alice") as alice, lab.client("bob") as bob:
        a_events, b_events = Events(), Events()
        alice.join("lobby", a_events)
        room = bob.join("lobby", b_events)
        assert room.members == ["alice", "bob"]
        wait_for(lambda: ("bob", "joined") in a_events.statuses(), 5, "alice to see bob join")
        alice.say("lobby", "hello bob")
        bob.say("lobby", "hi alice")
        for events in (a_events, b_events):
            wait_for(
                lambda ev=events: ev.lines() == [("alice", "hello bob"), ("bob", "hi alice")],
                5,
                "both lines at both users",
            )
        with lab.client("carol") as carol:
            late = carol.join("lobby")
            assert [(line.sender, line.text) for line in late.history] == [
                ("alice", "hello bob"),
                ("bob", "hi alice"),
            ]
            assert late.members == ["alice", "bob", "carol"]
        wait_for(
            lambda: (
                ("carol", "disconnected") in a_events.statuses()
                or ("carol", "left") in a_events.statuses()
            ),
            5,
            "carol's leaving announced",
        )


def test_history_survives_a_room_restart(lab: ProcessLab) -> None:
    with lab.client("alice") as alice:
        alice.join("lobby")
        alice.say("lobby", "remember me")
    room = next(p for p in lab.procs.started if p.name == "room-lobby")
    room.kill9()
    lab.start_room("lobby")
    with lab.client("bob") as bob:
        assert [line.text for line in bob.join("lobby").history] == ["remember me"]


def test_kick_from_room_needs_the_permission_and_is_announced(lab: ProcessLab) -> None:
    with lab.client("alice") as alice, lab.client("bob") as bob, lab.client("ida") as ida:
        events = Events()
        alice.join("lobby", events)
        bob.join("lobby")
        ida.join("lobby")
        with pytest.raises(NotAllowed, match="'kick' permission"):
            bob.kick("lobby", "alice")
        ida.kick("lobby", "bob", "spamming")
        wait_for(lambda: ("bob", "kicked") in events.statuses(), 5, "the kick announced")
        kicked = next(e.status for e in events.items if e.status and e.status.status == "kicked")
        assert kicked.by == "ida" and kicked.reason == "spamming"
        assert "bob" not in alice.room("lobby").members
        with pytest.raises(NotAllowed, match="join room lobby first"):
            bob.say("lobby", "still here?")
        with pytest.raises(NotAllowed, match="removed from room lobby"):
            bob.join("lobby")


def test_per_context_grant_allows_kick_in_that_room_only(lab: ProcessLab) -> None:
    lab.start_room("other")
    with lab.client("admin") as admin:
        admin.grant("bob", "kick", "ctx/lobby")
    with lab.client("alice") as alice, lab.client("bob") as bob, lab.client("carol") as carol:
        for client in (alice, bob):
            client.join("lobby")
            client.join("other")
        carol.join("other")
        with pytest.raises(NotAllowed):
            bob.kick("other", "carol")
        bob.kick("lobby", "alice")


def test_limits_give_clear_errors(lab: ProcessLab) -> None:
    with lab.client("alice") as alice:
        alice.join("lobby")
        with pytest.raises(RequestFailed, match="line too long"):
            alice.say("lobby", "x" * 5000)
        with pytest.raises(RateLimited, match="too fast") as info:
            for i in range(30):
                alice.say("lobby", f"line {i}")
        assert info.value.retry_after > 0
        with pytest.raises(NotFound, match="room nowhere not found"):
            alice.join("nowhere")


def test_forged_replayed_raw_expired_and_revoked_messages_are_refused(lab: ProcessLab) -> None:
    from common.auth import RegistryIdentity

    realm = lab.router.realm
    key = keys.ctx_in(realm, "lobby")
    with lab.client("alice") as alice, lab.client("bob") as bob:
        events = Events()
        alice.join("lobby", events)
        bob.join("lobby")
        z = bob.z
        # a token from another registry key
        forged = issue_session(RegistryIdentity.generate(), realm, "bob", ["chat", "join"])
        z.put(key, forged.seal(key, ChatSay(text="forged")))
        # a replay of a real message
        genuine = bob.session.seal(key, ChatSay(text="once"))
        z.put(key, genuine)
        z.put(key, genuine)
        # a raw put from a process that never logged in
        z.put(key, b"\x81\xa4type\xa7ChatSay")
        # an expired token (signed by the real registry key, as a stolen old token would be)
        import time

        old = issue_session(lab.identity, realm, "bob", ["chat"], ttl=10, now=time.time() - 60)
        z.put(key, old.seal(key, ChatSay(text="expired")))
        # a revoked session: carol logs in, joins, logs out, then her old session speaks
        with lab.client("carol") as carol:
            carol.join("lobby")
            stolen = carol.session
            carol.logout()
            wait_for(lambda: "carol" not in alice.room("lobby").members, 5, "carol dropped")
            z.put(key, stolen.seal(key, ChatSay(text="revoked")))
        bob.say("lobby", "still working")
        wait_for(lambda: ("bob", "still working") in events.lines(), 5, "the room to keep working")
        assert events.lines() == [("bob", "once"), ("bob", "still working")]


def test_kick_from_server_revokes_drops_and_tells_the_user(lab: ProcessLab) -> None:
    with lab.client("alice") as alice, lab.client("bob") as bob, lab.client("admin") as admin:
        events = Events()
        alice.join("lobby", events)
        bob.join("lobby")
        told = []
        bob.on_kicked = told.append
        with pytest.raises(NotAllowed):
            alice.kick_from_server("bob")
        admin.kick_from_server("bob", "cheating")
        wait_for(lambda: told, 5, "bob to be told")
        assert told[0].reason == "cheating" and told[0].by == "admin"
        wait_for(lambda: ("bob", "kicked") in events.statuses(), 5, "the room to drop bob")
        with pytest.raises(Exception, match="revoked"):
            bob.say("lobby", "am I here?")


def test_private_messages_live_and_kept_for_offline_users(lab: ProcessLab) -> None:
    with lab.client("alice") as alice, lab.client("bob") as bob:
        got = []
        bob.on_private = got.append
        assert alice.send_private("bob", "psst") is True
        wait_for(lambda: got, 5, "the private message")
        assert (got[0].sender, got[0].text, got[0].kept) == ("alice", "psst", False)
        with lab.client("carol"):
            pass  # carol has logged in once: her mailbox key is known
        assert alice.send_private("carol", "see you later") is False
    with lab.client("carol") as carol:
        assert [(m.sender, m.text, m.kept) for m in carol.pending] == [
            ("alice", "see you later", True)
        ]


def test_a_message_sent_right_after_the_recipients_login_is_delivered_live(lab: ProcessLab) -> None:
    # The recipient is reachable from the moment its login succeeds: a message sent then is
    # not kept for its next login (it was, when presence was declared after the login reply).
    with lab.client("alice") as alice:
        for i in range(5):
            with lab.client("bob") as bob:
                got: list = []
                bob.on_private = got.append
                assert alice.send_private("bob", f"hello {i}") is True
                wait_for(lambda got=got: got, 5, "the private message")
                assert got[0].text == f"hello {i}" and not got[0].kept
                assert bob.pending == []


def test_directory_lists_server_users_and_rooms(lab: ProcessLab) -> None:
    with lab.client("alice") as alice, lab.client("admin") as admin:
        alice.join("lobby")
        admin.rename_server("Robotics 101")
        d = wait_for(
            lambda: (r := alice.directory()).contexts and r.contexts[0].members and r, 10, "dir"
        )
        assert d.server_name == "Robotics 101"
        assert set(d.users) >= {"alice", "admin"}
        lobby = d.contexts[0]
        assert (lobby.ctx, lobby.kind, lobby.owner, lobby.members) == (
            "lobby",
            "chat",
            "chat-lobby",
            ["alice"],
        )
