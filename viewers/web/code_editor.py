"""The workbench's code editor: CodeMirror 6 over viser's "Code" text area.

The editor is one vendored file, ``assets/wart-editor.js`` (CodeMirror 6, the
Python mode and the page's glue from ``assets/editor-src/editor.js``; rebuilt
by ``assets/build-editor.sh``, licences in ``assets/wart-editor.LICENSES.txt``).
Nothing is fetched from the internet: a lab may have none.

How it reaches the page. viser 1.1.1 serves files only from its own client
build directory, read by its websocket thread when the server starts, so the
viewer cannot add a file there without editing the installed package or
reaching into a running thread's closure. What viser does deliver is HTML:
``add_html`` puts markup in the page as is (``innerHTML``; labels.py and
masked.py rely on the same property). So the bundle travels once per browser
over the page's own websocket, as the text of a ``<script type="text/plain">``
(inert: the parser keeps its text, nothing runs it), and an ``<img>`` that
cannot load runs a one-line loader that evaluates that text in the page's
global scope (as a ``<script>`` would). It works offline, needs no second port, and
a later viser with a custom-element API would only change this loader.

How the text goes both ways. The workbench keeps its viser text area; the
editor hides it and is its only writer in the page: every edit is written into
it as typing would (React's value setter and an ``input`` event), so viser
sends it to the server in order, before any later button press; the server
setting the text area's value (opening a file) is noticed by the editor within
150 ms and loaded. The Python side therefore reads and writes ``code.value``
exactly as it did with a plain text area, and a browser without scripts still
has a working (plain) text area. Check's problems go the same way: an HTML
element whose ``data-problems`` attribute (JSON) the editor turns into gutter
markers with the message on hover.
"""

from __future__ import annotations

import html
import json
import threading
import weakref
from collections.abc import Iterable
from functools import cache
from pathlib import Path

import viser
from viser._messages import GuiUpdateMessage

from common.controller.advice import Problem
from viewers.web.inputs import set_value
from viewers.web.masked import element_id

ASSETS = Path(__file__).resolve().parent / "assets"
_LOADED: weakref.WeakSet[viser.ClientHandle] = weakref.WeakSet()  # browsers sent the bundle
_LOCK = threading.Lock()
BUNDLE = ASSETS / "wart-editor.js"

# Runs in the <img onerror>: turns the inert script text into a running script, once a page.
# Indirect eval runs it in the page's global scope, as a <script> would; a <script> with a
# Blob URL was tried first and did not run in Chromium from inside this handler.
LOADER_JS = (
    "if(!window.wartEditor){var t=document.getElementById('wart-editor-src');"
    "if(t){(0,eval)(t.textContent+'\\n//# sourceURL=wart-editor.js');}}"
)

# Tall enough to work in, short enough that the run's output below it stays in view on a
# 1280x800 laptop (12 to 40 lines as the window grows); its corner drags it taller.
EDITOR_CSS = """
.wart-editor .cm-editor { font-size: 13px; border: 1px solid #ced4da; border-radius: 4px;
  height: clamp(calc(12 * 1.45em + 12px), calc(100vh - 470px), calc(40 * 1.45em + 12px));
  resize: vertical; overflow: hidden; min-height: calc(8 * 1.45em + 12px); background: #fff; }
.wart-editor .cm-editor.cm-focused { outline: 2px solid #228be6; }
.wart-editor .cm-scroller { font-family: ui-monospace, Menlo, Consolas, monospace;
  line-height: 1.45; }
.wart-output { font-family: ui-monospace, Menlo, Consolas, monospace; font-size: 12px;
  white-space: pre-wrap; overflow-wrap: anywhere; margin: 0; }
.wart-output a[data-wart-line] { color: #1971c2; text-decoration: underline; cursor: pointer; }
"""


@cache
def bundle_html() -> str:
    """The editor's code (inert text) and the image that loads it; sent once per page."""
    source = BUNDLE.read_text(encoding="utf-8")
    # The only text that could end a <script> element early; esbuild never writes it.
    if "</script" in source.lower():
        raise ValueError(f"{BUNDLE} contains '</script'")
    return (
        f"<style>{EDITOR_CSS}</style>"
        f'<script type="text/plain" id="wart-editor-src">{source}</script>'
        f'<img src="data:," alt="" style="display:none" '
        f'onerror="{html.escape(LOADER_JS, quote=True)}">'
    )


def host_html(code: viser.GuiTextHandle, label: str, check: str, save: str) -> str:
    """The element the editor is drawn in, bound to the text area ``code``."""
    keys = json.dumps({"check": check, "save": save})
    return (
        f'<div class="wart-editor" data-for="{html.escape(element_id(code))}" '
        f'data-label="{html.escape(label)}" data-keys="{html.escape(keys)}"></div>'
    )


def problems_html(code: viser.GuiTextHandle, problems: Iterable[Problem]) -> str:
    """The gutter markers' data: each problem with a line, as JSON in an attribute."""
    data = [{"line": p.line, "message": p.message} for p in problems if p.line is not None]
    return (
        f'<div class="wart-problems" data-for="{html.escape(element_id(code))}" '
        f'data-problems="{html.escape(json.dumps(data))}"></div>'
    )


def show_text(code: viser.GuiTextHandle, text: str) -> None:
    """Put ``text`` in the editor on every page, even where the server holds it already.

    viser sends a value only when it changes at the server. But a page's resend that
    crossed the server's last text on the way can leave the server holding ``text``
    while that page shows another: a file opened then would never reach the page, and
    the page's next resend would put its own text back over the file.
    """
    if code.value != text:
        set_value(code, text)
        return
    code._impl.gui_api._websock_interface.queue_message(
        GuiUpdateMessage(code._impl.uuid, {"value": text})
    )


class CodeEditor:
    """The editor in the current GUI container, bound to the text area ``code``."""

    def __init__(
        self,
        client: viser.ClientHandle,
        code: viser.GuiTextHandle,
        *,
        label: str = "Controller code",
        check: str = "Check",
        save: str = "Save",
    ) -> None:
        self.code = code
        gui = client.gui
        # The bundle (446 kB) goes once per browser, not once per arena tab: once run,
        # the editor is the page's (window.wartEditor) and serves every tab.
        with _LOCK:
            first = client not in _LOADED
            _LOADED.add(client)
        self.bundle = gui.add_html(bundle_html()) if first else None
        self.host = gui.add_html(host_html(code, label, check, save))
        self.keys = gui.add_markdown(
            f"_Tab indents, Shift-Tab dedents; Esc then Tab leaves the editor; "
            f"Ctrl-Enter: {check}; Ctrl-S: {save}; Ctrl-F: search._"
        )
        self.markers = gui.add_html(problems_html(code, []))

    def mark(self, problems: Iterable[Problem]) -> None:
        content = problems_html(self.code, problems)
        if self.markers.content != content:
            self.markers.content = content
