"""The slot scheduler re-reads its world's agents when the world says its layout changed
(``world/<w>/layout``), not on anyone else's word, and never on a message it cannot read."""

from __future__ import annotations

import logging
import threading
from types import SimpleNamespace
from unittest import mock

from common.messages import WorldLayout, encode
from services.context.slots import SlotScheduler


def scheduler() -> SlotScheduler:
    state = SimpleNamespace(world="arena1", wake=threading.Condition(), room="arena")
    return SlotScheduler(
        state,  # type: ignore[arg-type]
        session=mock.MagicMock(),
        realm="lab",
        leases=mock.MagicMock(),
        runner_link=mock.MagicMock(),
        recorder=mock.MagicMock(),
        save=mock.MagicMock(),
        publish=mock.MagicMock(),
        publish_world_stop=mock.MagicMock(),
        log=logging.getLogger("test"),
    )


def news(payload: bytes) -> SimpleNamespace:
    return SimpleNamespace(payload=payload)


def test_a_new_layout_of_its_world_asks_for_the_snapshot_again() -> None:
    slots = scheduler()
    assert slots._need_snapshot()  # nothing read yet
    slots._layout = 3
    assert not slots._need_snapshot()
    slots.on_world_layout(news(encode(WorldLayout(world="arena1", layout=3))))
    assert not slots._need_snapshot(), "the layout it holds"
    slots.on_world_layout(news(encode(WorldLayout(world="arena1", layout=4))))
    assert slots._need_snapshot()


def test_another_worlds_layout_and_junk_are_ignored() -> None:
    slots = scheduler()
    slots._layout = 3
    slots.on_world_layout(news(encode(WorldLayout(world="arena2", layout=9))))
    slots.on_world_layout(news(b"\xc1 not msgpack"))
    slots.on_world_layout(news(encode(WorldLayout(world="arena1", layout=3))[:-1]))
    assert not slots._need_snapshot()
