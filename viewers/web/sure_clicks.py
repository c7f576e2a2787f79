"""Button clicks that always reach the server, though viser's page may drop them.

viser 1.1.1's page sends the panel's GUI messages through one 50 ms throttle
that keeps only the newest (viser/client/src/WebsocketUtils.ts,
``makeThrottledMessageSender``, used by ``ControlPanel/Generated.tsx``): a
click that waits in it behind an earlier message is replaced, silently, by
any GUI message that comes before the timer fires (a typed value, the code
editor's resend, a choice in a list). On a busy laptop the timer fires late
and the window grows; a student's 'Join' or 'Run' then does nothing, and the
page shows no sign of it (seen in a busy test run: the click never left).

The throttle is a closure inside React; what can be reached is the page's
one Web Worker, through which every message goes to the websocket
(``worker.postMessage({type: "send", message})``). So this script, run once
a page (an ``<img>`` that cannot load, as labels.py does):

- wraps ``Worker.prototype.postMessage`` to note the time and element of
  each GUI message the page sends (and which worker sends them);
- notes each click on a panel button (its element id is the GUI element's
  uuid; an upload button is left alone, its file is what it sends);
- once the page has sent another GUI message after the click and none for
  that button, the click was replaced: it sends the button's message itself,
  exactly as the button would have (``GuiUpdateMessage``, ``value: true``).

It never sends a click twice: the throttle either sends the click or sends a
newer message in its place, so "another message left, this one did not" is
proof the click was dropped; with no other message it only waits (a late
timer). A click the throttle merely delays is left to it. Values typed or
chosen are not covered here: the newest value is what counts, and the code
editor resends its text itself (assets/editor-src/editor.js).
"""

from __future__ import annotations

import html

import viser

# How long after a click to look, and how often, before giving up (ms): the
# throttle's timer fires 50 ms after the last send, later on a busy machine.
FIRST_LOOK_MS = 100
LOOK_EVERY_MS = 100
LOOKS = 100

SURE_CLICKS_JS = """
(function () {
  if (window.__wartSureClicks) return;
  window.__wartSureClicks = {resent: 0};
  var UUID = /^[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}$/;
  var GUI = /^Gui(Update|ButtonHold|FormSubmit|FormDirty)Message$/;
  var sent = [];
  var worker = null;
  var post = Worker.prototype.postMessage;
  Worker.prototype.postMessage = function (data) {
    var m = data && data.type === 'send' ? data.message : null;
    if (m && GUI.test(m.type)) {
      worker = this;
      sent.push([performance.now(), m.uuid]);
      if (sent.length > 400) sent.splice(0, 200);
    }
    return post.apply(this, arguments);
  };
  function look(uuid, at, left) {
    var own = false, other = false;
    for (var i = sent.length - 1; i >= 0 && sent[i][0] >= at; i--) {
      if (sent[i][1] === uuid) own = true; else other = true;
    }
    if (own) return;
    if (other && worker) {
      var message = {type: 'GuiUpdateMessage', uuid: uuid, updates: {value: true}};
      sent.push([performance.now(), uuid]);
      post.call(worker, {type: 'send', message: message});
      window.__wartSureClicks.resent += 1;
      console.warn('wart: a click was dropped by the page\\'s message throttle; sent again');
      return;
    }
    if (left > 0) setTimeout(function () { look(uuid, at, left - 1); }, EVERY);
  }
  document.addEventListener('click', function (e) {
    var b = e.target && e.target.closest ? e.target.closest('button') : null;
    if (!b || b.disabled || !UUID.test(b.id)) return;
    if (document.getElementById('file_upload_' + b.id)) return;
    var at = performance.now();
    setTimeout(function () { look(b.id, at, LOOKS); }, FIRST);
  }, true);
})();
"""


def sure_clicks_html() -> str:
    script = (
        SURE_CLICKS_JS.replace("FIRST", str(FIRST_LOOK_MS))
        .replace("EVERY", str(LOOK_EVERY_MS))
        .replace("LOOKS", str(LOOKS))
    )
    script = " ".join(line.strip() for line in script.strip().splitlines())
    return (
        '<img src="data:," alt="" style="display:none" '
        f'onerror="{html.escape(script, quote=True)}">'
    )


def add_sure_clicks(gui: viser.GuiApi) -> viser.GuiHtmlHandle:
    """Make this page's button clicks reach the server (once per page; more is harmless)."""
    return gui.add_html(sure_clicks_html())
