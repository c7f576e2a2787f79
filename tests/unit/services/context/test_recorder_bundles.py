"""The slot recorder keeps a swarm's commands from a MacCommandBundle: only its run's.

The recorder's writer is faked (it keeps what it is given); what is tested is
which bundle items become command records: those of the recorded agent MACed
with its run's lease key within the slot, and none other.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from common import keys
from common.messages import (
    MAC_ITEM_COUNTERS,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    MacCommandBundle,
    encode,
)
from common.recording import schema as s
from common.world.leasemac import CommandMac, new_lease_key
from services.context.agent_queue import ControlJob, RunningJob
from services.context.recorder import SlotRecorder, _Run

REALM, WORLD = "lab", "w1"


class FakeWriter:
    def __init__(self) -> None:
        self.records: list[tuple[str, Any]] = []

    def write(self, topic: str, record: Any, t: float | None = None) -> None:
        self.records.append((topic, record))


def recorder_of(agent: str, lease_key: bytes) -> tuple[SlotRecorder, _Run]:
    recorder = SlotRecorder(
        None,  # type: ignore[arg-type]  # no Zenoh: items are handed in directly
        REALM,
        "ctx",
        WORLD,
        None,
        b"\x00" * 32,
        logging.getLogger("test"),
    )
    now = time.time()
    job = ControlJob("r1", agent, "alice", b"\x01" * 16, "remote")
    run = RunningJob(job, "L1", b"\x01" * 16, now - 1, now + 60, lease_key=lease_key)
    rec = _Run(run=run, driver="alice", writer=FakeWriter())  # type: ignore[arg-type]
    recorder._runs["r1"] = rec
    recorder._agents[agent] = "r1"
    return recorder, rec


def item(mac: CommandMac, agent: str, seq: int, **kw: Any) -> tuple[str, bytes, bytes]:
    speeds, counters = kw.get("speeds", (4, 5)), kw.get("counters")
    flags = (MAC_ITEM_SPEEDS if speeds else 0) | (MAC_ITEM_COUNTERS if counters else 0)
    record = MAC_ITEM_STRUCT.pack(
        seq, kw.get("sent_at", time.time()), flags, *(speeds or (0, 0)), *(counters or (0, 0))
    )
    return agent, record, mac.item_tag(record)


def payload(items: list[tuple[str, bytes, bytes]]) -> bytes:
    return encode(
        MacCommandBundle(
            agents=[a for a, _, _ in items],
            items=b"".join(r for _, r, _ in items),
            macs=b"".join(m for _, _, m in items),
        )
    )


def commands(rec: _Run) -> list[tuple[str, tuple[int, int] | None, tuple[int, int] | None]]:
    writer = rec.writer
    assert isinstance(writer, FakeWriter)
    return [
        (r.auth, r.speeds, r.counters)
        for topic, r in writer.records
        if topic == s.commands_topic("k1") and isinstance(r, s.CommandRecord)
    ]


def test_the_runs_macd_items_are_recorded_and_forged_or_foreign_ones_are_not() -> None:
    k = new_lease_key()
    recorder, rec = recorder_of("k1", k)
    mine = CommandMac(k, keys.agent_cmd(REALM, WORLD, "k1"), "L1")
    guessed = CommandMac(new_lease_key(), keys.agent_cmd(REALM, WORLD, "k1"), "L1")
    items = [
        item(mine, "k1", 1, speeds=(4, 5)),
        item(guessed, "k1", 2),  # not the run's key
        item(mine, "k1", 3, sent_at=time.time() + 600),  # outside the slot
        item(mine, "k2", 4),  # another agent: not recorded here
        item(mine, "k1", 5, speeds=None, counters=(7, 8)),
    ]
    recorder.commands.bundle(payload(items), time.time())
    assert commands(rec) == [("mac", (4, 5), None), ("mac", None, (7, 8))]
    assert rec.refused == 2
    recorder.commands.bundle(b"\xc1garbage", time.time())  # malformed: ignored, nothing recorded
    assert len(commands(rec)) == 2


def test_items_under_a_lease_without_a_key_are_never_recorded() -> None:
    recorder, rec = recorder_of("k1", b"")  # a signed-only lease
    unkeyed = CommandMac(b"", keys.agent_cmd(REALM, WORLD, "k1"), "L1")  # anyone can make it
    recorder.commands.bundle(payload([item(unkeyed, "k1", 1)]), time.time())
    assert commands(rec) == [] and rec.refused == 1


def test_a_run_records_the_snapshot_the_slot_engine_handed_over(tmp_path) -> None:
    """No query of its own at the run's start: the world may not answer in a short slot."""
    from common.messages import WorldSnapshot
    from common.recording import read_recording
    from common.recording.store import RecordingStore

    class NoWorld:  # a session whose world never answers: any query fails the test
        def get(self, *_a: Any, **_k: Any) -> list[Any]:
            raise AssertionError("the recorder asked the world for its snapshot")

        def declare_subscriber(self, *_a: Any, **_k: Any) -> Any:  # the cameras' videos
            return type("Subscriber", (), {"undeclare": lambda self: None})()

    recorder = SlotRecorder(
        NoWorld(),  # type: ignore[arg-type]
        REALM,
        "ctx",
        WORLD,
        RecordingStore(tmp_path, keep=4),
        b"\x00" * 32,
        logging.getLogger("test"),
    )
    snap = WorldSnapshot(
        world=WORLD, tick=1, sim_time=0.01, layout=3, tick_s=0.01, seed=1, width=1000.0,
        height=1000.0, items=[], lights=[], agents=[], rows=["k0"], kind="real",
    )  # fmt: skip
    recorder.world_snapshot(snap)
    now = time.time()
    job = ControlJob("r1", "k0", "alice", b"\x01" * 16, "remote")
    run = RunningJob(job, "L1", b"\x01" * 16, now, now + 2)
    recorder.run_started(run, "alice")
    recorder.run_ended("r1", "finished", "its slot ended")
    while not recorder._queue.empty():  # what the writer thread does, in this thread
        kind, *args = recorder._queue.get_nowait()
        {"snapshot": recorder._note_snapshot, "start": recorder._start, "end": recorder._end}[kind](
            *args
        )
    recorder._close_due(float("inf"))
    recording = read_recording(recorder.store.path_for("alice", "r1"))  # type: ignore[union-attr]
    assert recording.snapshot is not None and recording.snapshot.layout == 3
