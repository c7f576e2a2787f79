"""Which tab is in front in the browser, told to the viewer: the world view follows it.

viser 1.1.1 tells the server nothing about tab clicks: a tab group keeps the
tab its user last pressed, in the page only. As in drive_keys.py, an
``add_html`` image that cannot load runs a fixed script (the input's id goes in
as JSON; nothing from users): a MutationObserver watches the tabs'
``aria-selected`` and writes the labels of the selected tabs, one per line, into
a text input the panel hides, with the setter React watches, so the text
reaches the viewer over the page's websocket like any input. The viewer then
shows the world of the arena whose tab is in front (client.py).
"""

from __future__ import annotations

import html
import json
import threading
import time
from collections.abc import Callable

import viser

from viewers.web.masked import INPUT_OF_JS, element_id

# The tabs as the page opens are not news: only a change is sent (a write at load time fell
# in viser's throttle beside the person's first click, and sure_clicks.py resent the click).
# No // comments inside: the script is joined into one line.
FRONT_TAB_JS = """
(function (id) {
  window.__wartFront = window.__wartFront || {};
  if (window.__wartFront[id]) return;
  window.__wartFront[id] = true;
  var setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
  var last = null, pending = false;
  INPUT_OF
  function selected() {
    return Array.prototype.map.call(
      document.querySelectorAll('[role=tab][aria-selected=true]'),
      function (t) { return t.textContent.trim(); }).join('\\n');
  }
  function check() {
    pending = false;
    var names = selected();
    if (names === last) return;
    var el = input();
    if (!el) return;
    last = names;
    setter.call(el, names);
    el.dispatchEvent(new Event('input', { bubbles: true }));
  }
  function soon() { if (!pending) { pending = true; setTimeout(check, 50); } }
  last = selected();
  new MutationObserver(soon).observe(document.body, {
    subtree: true, childList: true, attributes: true, attributeFilter: ['aria-selected'] });
})(ID);
"""


def front_tab_html(front: viser.GuiTextHandle) -> str:
    ident = element_id(front)
    script = FRONT_TAB_JS.replace("INPUT_OF", INPUT_OF_JS).replace("ID", json.dumps(ident))
    script = " ".join(line.strip() for line in script.strip().splitlines())
    hide = f'div:has(> * > * > label[for="{ident}"]) {{ display: none !important; }}'
    return (
        f"<style>{hide}</style>"
        f'<img src="data:," alt="" style="display:none" onerror="{html.escape(script)}">'
    )


EXPECT_S = 10.0  # how long a tab the server brought to the front may take to be reported


class FrontTab:
    """The labels of the tabs in front in this browser; ``on_change`` is called with them.

    After :meth:`expect` (the server brought a tab to the front), a report without that
    tab is one the page sent before it got there: it is kept, not acted on, until the
    page reports the tab or EXPECT_S passes (a late report of the arena left behind
    showed it again and dropped the student's selection in the one just joined).
    """

    def __init__(self, gui: viser.GuiApi, on_change: Callable[[tuple[str, ...]], None]) -> None:
        self.labels: tuple[str, ...] = ()
        self._input = gui.add_text("Tab in front", "")
        gui.add_html(front_tab_html(self._input))
        self._on_change = on_change
        self._lock = threading.Lock()
        self._expected: tuple[str, float] | None = None  # the label, and until when
        self._held = False  # a report kept back while a tab is expected
        self._input.on_update(lambda _: self._changed())

    def expect(self, label: str) -> None:
        """The server is bringing ``label``'s tab to the front: earlier reports are stale."""
        with self._lock:
            self._expected = (label, time.monotonic() + EXPECT_S)
        timer = threading.Timer(EXPECT_S + 0.1, self._expired)
        timer.daemon = True
        timer.start()

    def _changed(self) -> None:
        # Bounded: the page's tabs' labels, never more than a few short lines.
        labels = tuple(line[:200] for line in self._input.value.splitlines()[:20] if line)
        with self._lock:
            if labels == self.labels:
                return
            self.labels = labels
            expected = self._expected
            if expected is not None:
                label, until = expected
                if label not in labels and time.monotonic() < until:
                    self._held = True
                    return
                self._expected, self._held = None, False
        self._on_change(labels)

    def _expired(self) -> None:
        """The expected tab never came: the page's last report stands."""
        with self._lock:
            expected = self._expected
            if expected is None or time.monotonic() < expected[1]:
                return
            self._expected = None
            held, self._held = self._held, False
            labels = self.labels
        if held:
            self._on_change(labels)
