"""An arena whose world does not answer yet is shown once it answers, but only if the
student has not moved on to another arena's tab meanwhile (a late answer took the
page away from the arena the student was looking at, and dropped its selection).

The viser client and the lab connection are mocks; the retry thread is the panel's own.
"""

from __future__ import annotations

import threading
from unittest import mock

import pytest

from common.client.lab_address import parse_address
from common.lab_errors import NotAnswering
from viewers.web import chat_panel
from viewers.web.adapters import JoinedContext
from viewers.web.chat_panel import ChatPanel

ARENA = JoinedContext("arena1", "agent", "Arena", "ida", ("bob",), (), world="w1")


@pytest.fixture
def late_panel(monkeypatch: pytest.MonkeyPatch) -> tuple[ChatPanel, list[object], threading.Event]:
    """A panel whose first ask for its world finds it not answering; the next one answers
    once the test sets the returned event."""
    monkeypatch.setattr(chat_panel, "WORLD_RETRY_S", 0.01)
    monkeypatch.setattr(chat_panel, "RobotPanel", mock.MagicMock())  # not what is tested
    answer = threading.Event()
    feed = object()

    def world(name: str) -> object:
        if not answer.is_set():
            raise NotAnswering(f"{name} does not answer yet")
        return feed

    connection = mock.MagicMock()
    connection.world.side_effect = world
    connection.address = parse_address("lab.example.org/walk")
    connection.user = "bob"
    shown: list[object] = []
    panel = ChatPanel(
        mock.MagicMock(),
        mock.MagicMock(),
        connection,
        ARENA,
        on_close=lambda _: None,
        on_watch=lambda f, p: shown.append(f),
    )
    panel.show_world()
    assert shown == [] and "It is shown once it answers" in panel.notice.content
    return panel, shown, answer


def _retry_ended(panel: ChatPanel) -> bool:
    for _ in range(500):
        with panel._retry_lock:
            if not panel._retrying:
                return True
        threading.Event().wait(0.01)
    return False


def test_a_late_arena_is_shown_when_its_tab_is_still_in_front(late_panel) -> None:
    panel, shown, answer = late_panel
    answer.set()
    assert _retry_ended(panel)
    assert len(shown) == 1 and panel.notice.visible is False


def test_a_late_arena_does_not_take_the_page_from_the_arena_in_front(late_panel) -> None:
    panel, shown, answer = late_panel
    panel.in_front = False  # the student joined another arena, its tab in front
    answer.set()
    assert _retry_ended(panel)
    assert shown == []
    panel.in_front = True  # back on its tab: the client asks again, and it is shown
    panel.show_world()
    assert len(shown) == 1
