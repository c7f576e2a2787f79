"""Deleting anything from the arena in the page logs no traceback (against a real lab).

ida (edit_map) adds two robots and a ball with the map editor, selects the robot added
last (the last row of the world's frames: the view's selection must not outlive it, or
the frame pump meets an index past the robots' end), deletes it, the ball, and then
every robot down to none. The viewer runs in this process: caplog sees its log.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.browser.conftest import wait_until
from tests.browser.test_real_agents import enter_arena
from tests.browser.test_real_lab import session_of
from tests.kit.reallab import RealLab, real_lab

pytestmark = [pytest.mark.integration, pytest.mark.real_lab]


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    tmp = Path(tmp_path_factory.mktemp("deletelab"))
    with real_lab(tmp, "empty", agents=True) as env:  # one Khepera, k1, at the centre
        yield env


def test_deleting_robots_and_a_ball_logs_nothing(
    open_page, lab: RealLab, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="wart")
    ida = open_page("ida")
    panel = enter_arena(ida, lab, "ida")
    view = session_of(lab.viewer, "ida").view
    editor = panel.editor
    assert editor is not None and editor.allowed
    wait_until(lambda: view.snapshot is not None and view.frames_applied > 0, what="the arena")
    ida.p.get_by_text("Map editor").first.click()
    for n in (2, 3):  # each beside the ones before: the centre is taken
        ida.click("Add robot")
        wait_until(lambda n=n: len(view.robot_names) == n, 15, what=f"{n} robots in the view")
    ida.click("Add ball")
    wait_until(lambda: view.snapshot is not None and view.snapshot.balls, 15, what="the ball")
    ball = view.snapshot.balls[0].ident

    def delete(name: str, *, robot: bool) -> None:
        if robot:
            view.select(view.robot_names.index(name))
        else:
            editor.select(name)
        wait_until(lambda: editor.selected == name, 10, what=f"{name} selected in the editor")
        ida.click("Delete selected")
        wait_until(
            lambda: (
                name not in view.robot_names
                and all(b.ident != name for b in (view.snapshot.balls if view.snapshot else ()))
            ),
            15,
            what=lambda: f"{name} gone ({editor.notice.content})",
        )
        before = view.frames_applied
        wait_until(lambda: view.frames_applied > before + 2, 10, what="frames after the delete")

    last = view.robot_names[-1]
    delete(last, robot=True)  # the selected robot, the frame's last row
    assert view.selected is None and editor.selected is None
    delete(ball, robot=False)
    for name in list(view.robot_names):
        delete(name, robot=True)
    assert view.robot_names == ()
    problems = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert not problems, "\n".join(r.getMessage() + (r.exc_text or "") for r in problems)
