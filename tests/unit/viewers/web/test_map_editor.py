"""The map editor's handles follow the view's selection, whenever the editor is bound.

The viser client is a mock (its calls are what is checked); the world is the demo
world the viewer's own demo lab serves.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from types import SimpleNamespace
from unittest import mock

import pytest

from viewers.web.demo_world import DemoWorld
from viewers.web.editor import MapEditor


@pytest.fixture
def world() -> Iterator[DemoWorld]:
    world = DemoWorld("arena", 3, start=False)
    world.produce(1.0)  # one frame: the robots' poses
    yield world
    world.stop()


def a_view(selected: int | None, names: tuple[str, ...]) -> SimpleNamespace:
    return SimpleNamespace(
        selected=selected,
        selected_name=None if selected is None else names[selected],
        snapshot=None,
        on_select=[],
        on_obstacle_click=[],
    )


def handles_on(client: mock.MagicMock) -> list[str]:
    return [c.args[0] for c in client.scene.add_transform_controls.call_args_list]


def test_a_robot_selected_before_the_editor_is_bound_gets_handles(world: DemoWorld) -> None:
    # A busy page: the student clicked k1 before the arena's editor was bound to the view.
    client = mock.MagicMock()
    editor = MapEditor(client, allowed=True)
    view = a_view(1, world.snapshot().robots)
    editor.bind(view, world)  # type: ignore[arg-type]
    assert editor.selected == world.snapshot().robots[1]
    assert editor.selected_kind == "agent"
    assert handles_on(client) == ["/editor/gizmo"]


def test_a_driven_robot_or_a_watcher_gets_no_handles(world: DemoWorld) -> None:
    names = world.snapshot().robots
    watcher = mock.MagicMock()
    MapEditor(watcher, allowed=False).bind(a_view(0, names), world)  # type: ignore[arg-type]
    assert handles_on(watcher) == []

    client = mock.MagicMock()
    editor = MapEditor(client, allowed=True)
    editor.driven = lambda name: name == names[0]
    editor.bind(a_view(0, names), world)  # type: ignore[arg-type]
    assert editor.selected is None and handles_on(client) == []


def test_nothing_selected_binds_without_handles(world: DemoWorld) -> None:
    client = mock.MagicMock()
    editor = MapEditor(client, allowed=True)
    editor.bind(a_view(None, world.snapshot().robots), world)  # type: ignore[arg-type]
    assert editor.selected is None and handles_on(client) == []


def test_handles_made_from_two_threads_at_once_are_made_one_after_the_other(
    world: DemoWorld,
) -> None:
    # The bind's own selection and a click's (the view's thread) at once: viser removed one
    # handle of a name while another of that name was being made (a busy machine's run).
    client = mock.MagicMock()
    inside, overlaps = [0], []
    guard = threading.Lock()

    def make(*args: object, **kwargs: object) -> mock.MagicMock:
        with guard:
            inside[0] += 1
            overlaps.append(inside[0])
        time.sleep(0.005)
        with guard:
            inside[0] -= 1
        return mock.MagicMock()

    client.scene.add_transform_controls.side_effect = make
    editor = MapEditor(client, allowed=True)
    names = world.snapshot().robots
    editor.bind(a_view(None, names), world)  # type: ignore[arg-type]
    threads = [
        threading.Thread(target=lambda n=name: [editor.select(n) for _ in range(20)])
        for name in names
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(overlaps) == 20 * len(names) and max(overlaps) == 1
    assert editor.selected in names and editor._gizmo is not None
