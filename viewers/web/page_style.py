"""The page's own style rules, for a laptop's 1280x800 as much as for a wide screen.

viser lays the panel out; these rules only keep its content usable there: a
wide table (the class, the audit trail, the robots) scrolls sideways inside
the panel instead of being cut at its edge, and the panel's edge, which a
person can drag to widen it, shows a grip where viser draws none.
"""

from __future__ import annotations

import viser

PAGE_CSS = """
table.mantine-Table-table { display: block; max-width: 100%; overflow-x: auto; }
[data-dock-region-resize]::after {
  content: ""; position: absolute; top: 50%; left: 5px; width: 5px; height: 56px;
  margin-top: -28px; border-radius: 3px; background: #adb5bd; opacity: 0.9;
  pointer-events: none; }
[data-dock-region-resize]:hover::after { background: #228be6; }
"""


def add_page_style(gui: viser.GuiApi) -> viser.GuiHtmlHandle:
    """The rules above, once in this browser's page (an element that takes no room)."""
    return gui.add_html(f"<style>{PAGE_CSS}</style>")
