"""Driving a taken-over robot by keyboard: arrow keys or WASD while the driving box or the
world view has focus.

viser has no keyboard events, so, as in masked.py and labels.py, an
``add_html`` element carries an ``<img>`` that cannot load whose ``onerror``
runs a fixed script (nothing from users in it; the ids go in as JSON). The
script listens for keys only while the driving box (a focusable element of its
own) or the world view's canvas (made focusable, so a click on it focuses it)
has focus, and keeps them from viser's own keyboard camera (which listens on the
document after this capturing listener: WASD and the arrows would also fly and
tip the view), and writes the held directions with a sequence number, ``"fl 17"``,
into a text input the panel hides, with the setter React watches (as the code
editor does): the text reaches the viewer over the page's websocket like any
input. It writes again on every change and every 200 ms while keys are held
(a heartbeat: the viewer stops the robot when it hears nothing for 0.6 s, so
a page that closes or loses its connection mid-press stops the robot), and
"" at once when the keys are released or the box or view loses focus, the
window is left or the tab hidden (the deadman).
"""

from __future__ import annotations

import html
import json

import viser

from viewers.web.masked import INPUT_OF_JS, element_id

HEARTBEAT_MS = 200
DEADMAN_S = 0.6  # no word from the page for this long with keys held: the robot stops
BOX_LABEL = "Driving box: click here, then hold the arrow keys or W A S D to drive"

DRIVE_JS = """
(function (id, boxId) {
  window.__wartDrive = window.__wartDrive || {};
  if (window.__wartDrive[id]) return;
  window.__wartDrive[id] = true;
  var MAP = { ArrowUp: 'f', KeyW: 'f', ArrowDown: 'b', KeyS: 'b',
              ArrowLeft: 'l', KeyA: 'l', ArrowRight: 'r', KeyD: 'r' };
  var held = {}, seq = 0, timer = null;
  var setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
  INPUT_OF
  function ours(el) {
    return !!el && (el.id === boxId || el.tagName === 'CANVAS');
  }
  function send() {
    var el = input();
    if (!el) return;
    seq += 1;
    setter.call(el, Object.keys(held).sort().join('') + ' ' + seq);
    el.dispatchEvent(new Event('input', { bubbles: true }));
  }
  function beat() {
    if (Object.keys(held).length) { send(); return; }
    clearInterval(timer);
    timer = null;
  }
  function release() {
    if (!Object.keys(held).length) return;
    held = {};
    send();
  }
  document.addEventListener('keydown', function (e) {
    var d = MAP[e.code];
    if (!d || !ours(document.activeElement)) return;
    e.preventDefault();
    e.stopPropagation();
    if (!held[d]) { held[d] = 1; send(); }
    if (!timer) timer = setInterval(beat, BEAT);
  }, true);
  document.addEventListener('keyup', function (e) {
    var d = MAP[e.code];
    if (!d || !held[d]) return;
    e.stopPropagation();
    delete held[d];
    send();
  }, true);
  document.addEventListener('focusout', function (e) { if (ours(e.target)) release(); }, true);
  window.addEventListener('blur', release);
  document.addEventListener('visibilitychange', release);
  function focusable() {
    document.querySelectorAll('canvas').forEach(function (c) {
      if (!c.hasAttribute('tabindex')) c.tabIndex = 0;
    });
  }
  focusable();
  new MutationObserver(focusable).observe(document.body, { childList: true, subtree: true });
})(ID, BOX);
"""


def box_id(keys_input: viser.GuiTextHandle) -> str:
    return f"wart-drive-{element_id(keys_input)}"


def drive_html(keys_input: viser.GuiTextHandle) -> str:
    """The driving box, the style rule hiding the keys' input, and the script."""
    ident = element_id(keys_input)
    box = box_id(keys_input)
    script = (
        DRIVE_JS.replace("INPUT_OF", INPUT_OF_JS)
        .replace("ID", json.dumps(ident))
        .replace("BOX", json.dumps(box))
        .replace("BEAT", str(HEARTBEAT_MS))
    )
    script = " ".join(line.strip() for line in script.strip().splitlines())
    # The input's row stays in the page (the script writes to it) but takes no room.
    hide = f'div:has(> * > * > label[for="{ident}"]) {{ display: none !important; }}'
    return (
        f"<style>{hide}</style>"
        f'<div id="{box}" tabindex="0" role="application" aria-label="{html.escape(BOX_LABEL)}" '
        'style="box-sizing: border-box; width: 100%; border: 2px dashed #999; border-radius: 6px; '
        'padding: 10px; text-align: center; outline-offset: 2px">'
        "Driving box: click here, then hold ← ↑ → ↓ or W A S D</div>"
        f'<img src="data:," alt="" style="display:none" onerror="{html.escape(script)}">'
    )
