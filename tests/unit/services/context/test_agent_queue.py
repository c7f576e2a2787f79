"""The per-agent FIFO queues: order, positions, ETAs, disabling, vanished agents."""

from __future__ import annotations

import msgspec
import pytest

from common.messages import RequestStatus
from services.context.agent_queue import (
    ENDED_KEPT,
    ENDED_PER_USER,
    ControlJob,
    QueueBook,
    RunningJob,
    load_book,
    save_book,
)


def job(rid: str, agent: str = "k1", user: str = "alice") -> ControlJob:
    return ControlJob(request_id=rid, agent=agent, user=user, session_id=b"s" * 16, mode="remote")


def test_fifo_positions_and_etas() -> None:
    book = QueueBook(slot_seconds=10)
    book.set_agents({"k1": "khepera", "k2": "khepera"})
    assert book.add(job("a")) == 1 and book.add(job("b")) == 2
    first = book.next_to_start("k1")
    assert first is not None and first.request_id == "a"
    book.lines["k1"].running = RunningJob(first, "L", b"s" * 16, start=100.0, end=110.0)
    assert book.next_to_start("k1") is None  # one at a time
    assert book.eta("k1", 1, now=103.0) == 110.0
    queues = {q.agent: q for q in book.agent_queues(now=103.0)}
    assert [(e.request_id, e.position) for e in queues["k1"].entries] == [("a", 0), ("b", 1)]
    assert book.expired(109.0) == [] and book.expired(110.0)[0].job.request_id == "a"


def test_disabled_agents_do_not_start_and_have_no_eta() -> None:
    book = QueueBook(slot_seconds=10)
    book.set_agents({"k1": "khepera"})
    book.add(job("a"))
    book.lines["k1"].enabled = False
    assert book.next_to_start("k1") is None and book.eta("k1", 1, 0.0) is None
    book.lines["k1"].enabled = True
    book.enabled = False
    assert book.next_to_start("k1") is None
    book.enabled = True
    assert book.next_to_start("k1") is not None


def test_vanished_agents_give_back_their_jobs() -> None:
    book = QueueBook(slot_seconds=10)
    book.set_agents({"k1": "khepera", "k2": "khepera"})
    book.add(job("a", "k2"))
    gone = book.set_agents({"k1": "khepera"})
    assert [j.request_id for j in gone] == ["a"] and "k2" not in book.lines
    assert book.remove_waiting("zz") is None and book.find("a") is None


def test_a_saved_book_comes_back_whole() -> None:
    book = QueueBook(30.0)
    book.enabled = False
    book.set_agents({"k0": "khepera", "k1": "khepera"})
    book.add(ControlJob("k0-1", "k0", "alice", b"a" * 16, "remote"))
    book.add(ControlJob("k0-2", "k0", "bob", b"b" * 16, "deploy", source=b"print(1)"))
    book.lines["k1"].running = RunningJob(
        ControlJob("k1-1", "k1", "carol", b"c" * 16, "remote"),
        "L1",
        b"h",
        1.0,
        2.0,
        b"x",
        b"k" * 32,
    )
    back = load_book(save_book(book))
    assert back.slot_seconds == 30.0 and back.enabled is False
    assert [j.request_id for j in back.lines["k0"].waiting] == ["k0-1", "k0-2"]
    assert back.lines["k0"].waiting[1].source == b"print(1)"
    run = back.lines["k1"].running
    assert run is not None and (run.lease_id, run.end, run.lease_key) == ("L1", 2.0, b"k" * 32)
    with pytest.raises(ValueError, match="not a saved queue book"):
        load_book(b"junk")


def test_an_emergency_stop_holds_the_queues_in_order_and_survives_a_restart() -> None:
    book = QueueBook(30.0)
    book.set_agents({"k1": "khepera"})
    first = job("a")
    book.add(first)
    book.estop = "emergency stop by ida"
    assert book.next_to_start("k1") is None  # held, not dropped
    assert book.eta("k1", 1, 100.0) is None
    restored = load_book(save_book(book))
    assert restored.estop == "emergency stop by ida"
    restored.estop = ""
    assert restored.next_to_start("k1") == first


def ended(rid: str, user: str = "alice") -> RequestStatus:
    return RequestStatus(request_id=rid, agent="k1", user=user, status="finished", reason="r")


def test_ended_requests_are_kept_per_user_so_one_cannot_push_out_the_others() -> None:
    book = QueueBook(slot_seconds=10)
    book.record_end(ended("bob-1", user="bob"), 1.0)
    for i in range(ENDED_PER_USER + 5):  # alice queues and cancels in a loop
        book.record_end(ended(f"alice-{i}"), 2.0 + i)
    assert "bob-1" in book.ended
    mine = [rid for rid, end in book.ended.items() if end.status.user == "alice"]
    assert mine == [f"alice-{i}" for i in range(5, ENDED_PER_USER + 5)]  # her newest


def test_ended_requests_are_bounded_overall_oldest_first() -> None:
    book = QueueBook(slot_seconds=10)
    for i in range(ENDED_KEPT + 3):
        book.record_end(ended(f"r-{i}", user=f"u{i}"), float(i))
    assert len(book.ended) == ENDED_KEPT
    assert "r-2" not in book.ended and "r-3" in book.ended


def test_ended_requests_survive_a_save_and_a_book_saved_before_them_loads() -> None:
    book = QueueBook(slot_seconds=10)
    book.set_agents({"k1": "khepera"})
    book.record_end(ended("r-1"), 5.0)
    assert load_book(save_book(book)).ended == book.ended
    # A queues file written before the record existed: read as no ended requests.
    older = msgspec.msgpack.decode(save_book(book))
    del older["ended"]
    assert load_book(msgspec.msgpack.encode(older)).ended == {}


def test_a_take_over_shows_in_the_queues_and_survives_a_restart() -> None:
    book = QueueBook(60.0)
    book.set_agents({"k1": "khepera"})
    run = RunningJob(job("a"), "arena.a", b"s" * 16, start=100.0, end=160.0, lease_key=b"k" * 32)
    teacher = ControlJob("a", "k1", "ida", b"i" * 16, "remote")
    run.taken = RunningJob(teacher, "take-1.arena", b"i" * 16, 120.0, 160.0, lease_key=b"t" * 32)
    book.lines["k1"].running = run
    entry = book.agent_queues(now=130.0)[0].entries[0]
    assert (entry.user, entry.taken_by, entry.taken_at) == ("alice", "ida", 120.0)
    back = load_book(save_book(book)).lines["k1"].running
    assert back is not None and back.taken is not None
    assert (back.taken.job.user, back.taken.lease_id, back.taken.lease_key) == (
        "ida",
        "take-1.arena",
        b"t" * 32,
    )
    # Handed back: the student's lease from the hand-back on, nobody's take-over left.
    run.taken, run.lease_start = None, 140.0
    back = load_book(save_book(book)).lines["k1"].running
    assert back is not None and back.taken is None and back.lease_start == 140.0
    assert book.agent_queues(now=150.0)[0].entries[0].taken_by is None
