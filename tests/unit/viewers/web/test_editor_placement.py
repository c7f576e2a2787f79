"""Where the map editor asks for a new robot: the arena's centre ("Add robot") or the point
of a shift-click in the arena (the world then finds the free spot nearest to it).

The viser client is a mock; the world is the demo world, which records the edits it gets.
"""

from __future__ import annotations

from collections.abc import Iterator
from types import SimpleNamespace
from unittest import mock

import pytest

from viewers.web import geometry as geo
from viewers.web.demo_world import DemoWorld
from viewers.web.editor import MapEditor


@pytest.fixture
def world() -> Iterator[DemoWorld]:
    world = DemoWorld("arena", 3, start=False)
    world.produce(1.0)
    yield world
    world.stop()


def a_view() -> SimpleNamespace:
    return SimpleNamespace(
        selected=None, selected_name=None, snapshot=None, on_select=[], on_obstacle_click=[]
    )


def click(x_mm: float, y_mm: float) -> SimpleNamespace:
    """A click's ray from a camera 2 m above, aimed at (x, y) on the floor."""
    x, y = x_mm * geo.MM, y_mm * geo.MM
    return SimpleNamespace(ray_origin=(x - 0.5, y, 2.0), ray_direction=(0.2425, 0.0, -0.9701))


def test_a_shift_click_asks_for_a_robot_there(world: DemoWorld) -> None:
    client = mock.MagicMock()
    editor = MapEditor(client, allowed=True)
    editor.bind(a_view(), world)  # type: ignore[arg-type]
    client.scene.on_click.assert_called_once_with(modifier="shift")
    editor._add_at_click(click(300.0, 700.0))  # type: ignore[arg-type]
    (edit,) = world.edits
    assert (edit.op, edit.kind) == ("add", "agent")
    assert (edit.x, edit.y) == pytest.approx((300.0, 700.0), abs=0.5)
    along = SimpleNamespace(ray_origin=(0.0, 0.0, 2.0), ray_direction=(1.0, 0.0, 0.0))
    editor._add_at_click(along)  # type: ignore[arg-type]
    assert len(world.edits) == 1  # a ray along the floor asks for nothing
    editor.unbind()
    client.scene.remove_click_callback.assert_called_once()


def test_add_robot_asks_for_the_centre_and_a_watcher_gets_no_click(world: DemoWorld) -> None:
    client = mock.MagicMock()
    editor = MapEditor(client, allowed=True)
    editor.bind(a_view(), world)  # type: ignore[arg-type]
    editor._add("agent")
    snap = world.snapshot()
    assert (world.edits[0].x, world.edits[0].y) == (snap.width / 2, snap.height / 2)
    watcher = mock.MagicMock()
    MapEditor(watcher, allowed=False).bind(a_view(), world)  # type: ignore[arg-type]
    watcher.scene.on_click.assert_not_called()
