"""The map editor's handles: never on a robot someone's controller drives.

An instructor (ana, edit_map) watching the demo arena selects robots in her view:
an idle one gets the map editor's handles, one that a controller holds does not.
Decided by the server's state (the editor's gizmo), not by pixels.
"""

from __future__ import annotations

from tests.browser.conftest import join_demo_arena, wait_until
from viewers.web.app import WebViewer


def test_no_map_handles_on_a_driven_robot(open_page, viewer: WebViewer) -> None:
    _page, session = join_demo_arena(open_page, viewer, "ana")
    wait_until(lambda: any(lab.panels for lab in session.labs.values()), what="the arena panel")
    panel = next(tab for lab in session.labs.values() for tab in lab.panels.values())
    editor, robots, view = panel.editor, panel.robots, session.view
    assert editor is not None and robots is not None and editor.allowed
    wait_until(lambda: view.snapshot is not None and view.feed is not None, what="the arena")
    names = view.robot_names
    driven, idle = names[1], names[2]

    robots.connection.request_control(panel.ctx, driven, "spin.py", b"# a controller\n")
    wait_until(lambda: robots.driven(driven), 10, what=f"{driven} held by ana's controller")
    assert not robots.driven(idle)

    # A click selects a robot the view has drawn: its pose comes with the frames (a busy
    # machine's first frame came after this select, and the handles had no pose to go to).
    wait_until(lambda: view.frames_applied > 0, what="the arena's first frame in the view")
    # ... and the map editor bound to the arena and its frames (on a busy machine it came
    # after the click, which then went nowhere).
    wait_until(
        lambda: editor.feed is not None and editor.feed.latest() is not None,
        what="the map editor bound to the arena",
    )
    view.select(names.index(idle))
    wait_until(
        lambda: editor.selected == idle,
        10,
        what=lambda: f"handles on the idle robot (the view selected {view.selected_name})",
    )
    view.select(names.index(driven))
    wait_until(lambda: editor.selected is None, 10, what="no handles on the driven robot")
    assert editor._gizmo is None
