"""The camera reads its world's robots again when that world says its rows changed
(``world/<w>/layout``), not on another world's word, and a message it cannot read is
dropped and counted, the camera serving on."""

from __future__ import annotations

from types import SimpleNamespace
from unittest import mock

from common import keys
from common.messages import WorldLayout, encode
from services.camera.service import CameraService


def camera_and_news_handler() -> tuple[CameraService, mock.Mock]:
    """A camera over arena1 (its Zenoh session a mock) and the handler it subscribed to
    ``world/arena1/layout`` with: what the router would call."""
    session = mock.MagicMock()
    camera = CameraService(session, "lab", "arena1-cam", world="arena1", source=mock.Mock())
    camera._worker = mock.Mock()  # no capture thread: the handler is what is tested
    camera.on_start()
    handlers = {call.args[0]: call.args[1] for call in session.declare_subscriber.call_args_list}
    return camera, handlers[keys.world_layout("lab", "arena1")]


def news(payload: bytes) -> SimpleNamespace:
    return SimpleNamespace(payload=payload, key_expr="wart/lab/world/arena1/layout")


def test_its_worlds_news_makes_the_robots_due_at_the_next_frame() -> None:
    camera, handler = camera_and_news_handler()
    camera._next_layout = 1e12  # read a moment ago: the next check far away
    handler(news(encode(WorldLayout(world="arena1", layout=4))))
    assert camera._next_layout == 0.0


def test_another_worlds_news_and_junk_change_nothing() -> None:
    camera, handler = camera_and_news_handler()
    camera._next_layout = 1e12
    handler(news(encode(WorldLayout(world="arena2", layout=9))))
    handler(news(b"\xc1 not msgpack"))
    handler(news(encode(WorldLayout(world="arena1", layout=3))[:-1]))
    assert camera._next_layout == 1e12
    assert camera.dropped == 2  # the two it could not read; another world's is no fault
