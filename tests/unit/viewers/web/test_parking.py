"""A closed page's lab session parked for a reload: claimed by its own saved login only,
events kept in order, ended past the grace with words that say why."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest

from common.client.lab_address import LabAddress
from tests.kit.waits import wait_for
from viewers.web.adapters import (
    ChatEntry,
    ChatEvent,
    JoinedContext,
    LabError,
    LabEvent,
    LoginUnavailable,
)
from viewers.web.chat_panel import PanelMemory
from viewers.web.handover import EditorText
from viewers.web.parking import EventKeeper, LabMemory, ParkingLot
from viewers.web.workbench import BenchMemory

ADDRESS = LabAddress("lab.example.org", user="alice")
MEMORY = LabMemory(panels=(), private=("from bob: hi",), watching="arena")


class FakeConnection:
    """What the lot uses of a lab connection: its identity, events, directory and logout."""

    def __init__(self, token: bytes | None = b"token-of-alice", user: str = "alice") -> None:
        self.address = LabAddress("lab.example.org", user=user)
        self.user = user
        self.resume_token = token
        self.subscribers: list[Callable[[LabEvent], None]] = []
        self.logouts: list[tuple[bool, str]] = []
        self.revoked = False
        self.registry_down = False

    def subscribe(self, callback: Callable[[LabEvent], None]) -> Callable[[], None]:
        self.subscribers.append(callback)
        return lambda: self.subscribers.remove(callback)

    def emit(self, event: LabEvent) -> None:
        for callback in list(self.subscribers):
            callback(event)

    def check_resume(self) -> None:
        if self.registry_down:
            raise LoginUnavailable("the lab at lab.example.org does not answer")
        if self.revoked:
            raise LabError("your saved login was revoked (the password was changed)")

    def logout(self, keep_resume: bool = False, reason: str = "") -> None:
        self.logouts.append((keep_resume, reason))

    def hand_over(self) -> None:
        self.logouts.append((True, "handed over"))


def chat(n: int) -> ChatEvent:
    return ChatEvent("arena", ChatEntry(seq=n, sender="bob", text=f"line {n}", at=float(n)))


def park(lot: ParkingLot, conn: FakeConnection) -> None:
    lot.attach(conn)  # type: ignore[arg-type]
    assert lot.park(conn, MEMORY, EventKeeper(conn))  # type: ignore[arg-type]


def test_only_the_same_saved_login_takes_the_session_back() -> None:
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    park(lot, conn)
    assert lot.claim(ADDRESS.lab_key, "alice", b"another token", wait_s=0) is None
    assert lot.claim(ADDRESS.lab_key, "bob", b"token-of-alice", wait_s=0) is None
    other_lab = LabAddress("other.example.org").lab_key
    assert lot.claim(other_lab, "alice", b"token-of-alice", wait_s=0) is None
    back = lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0)
    assert back is not None and back.connection is conn and back.memory == MEMORY
    # Taken once: a replayed cookie finds nothing, and the session was never logged out.
    assert lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0) is None
    assert conn.logouts == []
    lot.close()


def test_past_the_grace_the_session_ends_and_says_why() -> None:
    lot = ParkingLot(grace_s=0.3)
    conn = FakeConnection()
    park(lot, conn)
    wait_for(lambda: conn.logouts != [], 10, what="the parked session's end")
    # The rooms are told why: a run that ends with it ends with these words.
    assert conn.logouts == [(True, "the page was closed for more than 0.3 s")]
    assert conn.subscribers == []  # its events are no longer kept
    assert lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0) is None
    assert len(lot) == 0
    lot.close()


def test_events_of_the_time_away_come_first_in_order_then_live_ones_none_twice() -> None:
    conn = FakeConnection()
    keeper = EventKeeper(conn)  # type: ignore[arg-type]
    for n in range(3):
        conn.emit(chat(n))
    seen: list[LabEvent] = []
    keeper.hand_to(seen.append)
    conn.emit(chat(3))
    assert [e.line.text for e in seen if isinstance(e, ChatEvent)] == [
        "line 0",
        "line 1",
        "line 2",
        "line 3",
    ]


def test_events_racing_the_hand_over_keep_their_order() -> None:
    conn = FakeConnection()
    keeper = EventKeeper(conn)  # type: ignore[arg-type]
    seen: list[int] = []
    stop = threading.Event()

    def lab_thread() -> None:
        n = 0
        while not stop.is_set() and n < 20_000:
            conn.emit(chat(n))
            n += 1

    thread = threading.Thread(target=lab_thread)
    thread.start()
    time.sleep(0.01)
    keeper.hand_to(lambda e: seen.append(int(e.line.text.split()[1])))  # type: ignore[union-attr]
    stop.set()
    thread.join()
    # From the oldest kept (the deque's bound drops the oldest, counted): none lost or twice.
    assert seen and seen == list(range(keeper.dropped, keeper.dropped + len(seen)))


def test_a_reload_whose_old_page_closes_late_still_finds_its_session() -> None:
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    lot.attach(conn)  # type: ignore[arg-type]  # the old page: still open for a moment
    closer = threading.Timer(0.3, lambda: lot.park(conn, MEMORY, EventKeeper(conn)))  # type: ignore[arg-type]
    closer.start()
    back = lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=10)
    assert back is not None and back.connection is conn
    lot.close()


def test_a_second_tab_beside_an_open_one_does_not_take_its_session() -> None:
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    lot.attach(conn)  # type: ignore[arg-type]  # the first tab stays open
    started = time.monotonic()
    assert lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0.2) is None
    assert time.monotonic() - started >= 0.2
    assert conn.logouts == []
    lot.close()


def test_a_check_the_registry_could_not_answer_ends_nothing_and_keeps_it_parked() -> None:
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    park(lot, conn)
    conn.registry_down = True  # restarting, or hung
    back = lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0)
    assert back is not None
    with pytest.raises(LoginUnavailable, match="does not answer"):
        lot.still_good(back)
    assert conn.logouts == [] and len(lot) == 1
    conn.registry_down = False  # the next reload, the registry back: the same session
    again = lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0)
    assert again is back and lot.still_good(again)
    lot.close()


def test_a_session_revoked_while_parked_is_ended_not_handed_back() -> None:
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    park(lot, conn)
    conn.revoked = True  # the password was changed meanwhile
    back = lot.claim(ADDRESS.lab_key, "alice", b"token-of-alice", wait_s=0)
    assert back is not None
    assert not lot.still_good(back)
    assert conn.logouts == [
        (
            True,
            "the saved login was refused when the page came back "
            "(your saved login was revoked (the password was changed))",
        )
    ]
    lot.close()


def test_without_a_saved_login_or_with_parking_off_nothing_is_kept() -> None:
    lot = ParkingLot(grace_s=60)
    no_token = FakeConnection(token=None)
    assert not lot.park(no_token, MEMORY, EventKeeper(no_token))  # type: ignore[arg-type]
    off = ParkingLot(grace_s=0)
    conn = FakeConnection()
    assert not off.enabled
    assert not off.park(conn, MEMORY, EventKeeper(conn))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="must be 0"):
        ParkingLot(grace_s=-1)
    lot.close()


def test_the_viewer_stopping_hands_every_parked_session_over_with_what_its_page_had() -> None:
    """Not logged out: the runs go on, and the page comes back to the next viewer."""
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    park(lot, conn)
    [(token, page)] = lot.close()
    assert conn.logouts == [(True, "handed over")]
    assert token == conn.resume_token and page.user == "alice"
    assert page.contexts == () and page.watching is None  # MEMORY has no panel to show
    assert not lot.park(conn, MEMORY, EventKeeper(conn))  # type: ignore[arg-type]


def test_a_page_reloading_as_the_viewer_stops_keeps_its_arena_and_unsaved_editor() -> None:
    lot = ParkingLot(grace_s=60)
    conn = FakeConnection()
    arena = JoinedContext("arena", "agent", "", "ida", ("alice",), (), world="arena1")
    bench = BenchMemory.of_text("mine.py", "# typed, never saved\n", "k2")
    memory = LabMemory((PanelMemory(arena, (), None, bench),), (), watching="arena")
    lot.attach(conn)  # type: ignore[arg-type]
    assert lot.park(conn, memory, EventKeeper(conn))  # type: ignore[arg-type]
    [(_, page)] = lot.close()
    assert page.contexts == ("arena",) and page.watching == "arena"
    assert page.editors == (EditorText("arena", "mine.py", "# typed, never saved\n", "k2"),)
