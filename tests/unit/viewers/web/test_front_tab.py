"""The tab in front, as the page reports it: a report sent before the page reached the tab
the server brought forward is stale, and is not acted on (it showed the arena left behind
again and dropped the student's selection in the one just joined).

The viser GUI is a mock; the page's reports are written into its hidden input by the test.
"""

from __future__ import annotations

from unittest import mock

import pytest

from viewers.web import front_tab
from viewers.web.front_tab import FrontTab


@pytest.fixture
def tab() -> tuple[FrontTab, list[tuple[str, ...]]]:
    seen: list[tuple[str, ...]] = []
    return FrontTab(mock.MagicMock(), seen.append), seen


def report(tab: FrontTab, *labels: str) -> None:
    tab._input.value = "\n".join(labels)
    tab._changed()


def test_a_report_is_acted_on_once(tab) -> None:
    front, seen = tab
    report(front, "lab@host", "real1 (arena)")
    report(front, "lab@host", "real1 (arena)")
    assert seen == [("lab@host", "real1 (arena)")]


def test_a_report_from_before_the_tab_the_server_brought_forward_is_not_acted_on(tab) -> None:
    front, seen = tab
    front.expect("w1 (arena)")
    report(front, "lab@host", "real1 (arena)")  # late: sent before the page got to w1
    assert seen == []
    report(front, "lab@host", "w1 (arena)")
    report(front, "lab@host", "real1 (arena)")  # the student clicks back: acted on
    assert seen == [("lab@host", "w1 (arena)"), ("lab@host", "real1 (arena)")]


def test_a_tab_that_never_comes_lets_the_last_report_stand(
    tab, monkeypatch: pytest.MonkeyPatch
) -> None:
    front, seen = tab
    monkeypatch.setattr(front_tab, "EXPECT_S", 0.05)
    front.expect("gone (arena)")
    report(front, "lab@host", "real1 (arena)")
    assert seen == []
    for _ in range(100):
        if seen:
            break
        front_tab.time.sleep(0.01)
    assert seen == [("lab@host", "real1 (arena)")]
