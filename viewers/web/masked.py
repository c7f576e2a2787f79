"""Password inputs: viser text inputs whose typed text is drawn as dots.

viser 1.1.1's text input has no mask option. Its HTML element, though, puts
its markup in the page as is (React's ``dangerouslySetInnerHTML``, no
sanitising), so a ``<style>`` element there styles the page. Each masked input
gets its own rule, keyed on the input's element id: viser draws its label as
``<label for="<id>">`` in a box beside the input's box (the input itself gets
another id from Mantine), so the rule goes from that label's box to the input
in the next box; ``#<id>`` is there too in case a later viser gives the input
that id. Nothing else is masked: the rule names one input only.

``-webkit-text-security: disc`` is supported by Chromium and WebKit. The typed
text still reaches the viewer as every viser input does (over the page's
websocket); callers empty the field as soon as they have used it.
"""

from __future__ import annotations

import viser

MASK = "-webkit-text-security: disc !important;"


def mask_rule(element_id: str) -> str:
    """The CSS that masks the text input labelled by ``<label for=element_id>``."""
    if not element_id or any(c in element_id for c in '"\\<>{}'):
        raise ValueError(f"not an element id: {element_id!r}")
    beside = f'div:has(> * > label[for="{element_id}"]) + div'
    return (
        f"{beside} input, {beside} textarea {{ {MASK} }}\n"
        f'input[id="{element_id}"], textarea[id="{element_id}"] {{ {MASK} }}'
    )


def element_id(handle: viser.GuiTextHandle) -> str:
    # viser 1.1.1 keeps a GUI element's id (its label's `for`) only on the handle's
    # private state; there is no public accessor.
    return str(handle._impl.uuid)


def add_masked_text(gui: viser.GuiApi, label: str, initial_value: str = "") -> viser.GuiTextHandle:
    """A text input (in the current container) that shows dots instead of what is typed."""
    handle = gui.add_text(label, initial_value)
    # An empty <div> with a <style> in it: it takes no room in the panel.
    gui.add_html(f"<style>{mask_rule(element_id(handle))}</style>")
    return handle
