"""viser's inputs, typed: ``set_value(handle, value)``, ``on_click(button, action)``.

viser declares the ``value`` setter apart from its getter (another method
lies between them), and mypy then reads the property as read-only: every
``handle.value = x`` was a type error. At run time the setter is there and
sends the new value to the browsers; :func:`set_value` is that assignment,
written once. A click callback is typed as returning None (or a coroutine,
which viser awaits): :func:`on_click` runs an action whose result the page
does not need, such as a method that also returns what it did.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import viser

T = TypeVar("T")


def set_value(handle: viser.GuiInputHandle[T], value: T) -> None:
    """``handle.value = value``: shown in every browser that has the input."""
    handle.value = value  # type: ignore[misc]  # the setter mypy does not see (above)


def on_click(button: viser.GuiButtonHandle, action: Callable[[], object]) -> None:
    """Run ``action()`` on each click of ``button`` (in viser's thread pool); its result dropped."""

    def clicked(_event: viser.GuiEvent[viser.GuiButtonHandle]) -> None:
        action()

    button.on_click(clicked)
