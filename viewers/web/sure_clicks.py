"""Clicks and typed values that reach the server, though viser's page may drop them.

viser 1.1.1's page sends the panel's GUI messages through one 50 ms throttle
that keeps only the newest (viser/client/src/WebsocketUtils.ts,
``makeThrottledMessageSender``, used by ``ControlPanel/Generated.tsx``): a
message that waits in it behind an earlier one is replaced, silently, by any
GUI message that comes before the timer fires. On a busy laptop the timer
fires late and the window grows. A student's 'Join' or 'Run' then does
nothing, and the page shows no sign of it (seen in a busy test run: the click
never left); or a click replaces the last letters typed just before it, and
the server acts on the text as it was (Connect to the address before the
edit).

The throttle is a closure inside React; what can be reached is the page's
one Web Worker, through which every message goes to the websocket
(``worker.postMessage({type: "send", message})``). So this script, run once
a page (an ``<img>`` that cannot load, as labels.py does):

- wraps ``Worker.prototype.postMessage`` to note the time and element of
  each GUI message the page sends (and which worker sends them);
- notes each edit of a text input or text area, each tick of a checkbox and
  each option clicked in a dropdown (before React sees it, in the capture
  phase; a dropdown's input carries the element's uuid, its options their
  values); when a GUI message of another
  element is about to leave while such an edit's own message has not, the
  edit's was replaced: its value, read from the element, is sent first, so
  the click that replaced it acts on what the student typed;
- notes each click on a panel button (its element id is the GUI element's
  uuid; an upload button is left alone, its file is what it sends); once the
  page has sent another GUI message after the click and none for that
  button, the click was replaced: it sends the button's message itself,
  exactly as the button would have (``GuiUpdateMessage``, ``value: true``).

A click is never sent twice: the throttle either sends the click or sends a
newer message in its place, so "another message left, this one did not" is
proof the click was dropped. (Each GUI container has its own throttle, the
panel and each modal; a message of another container leaving first proves
nothing, but the first look comes after the click's own throttle has fired:
its timer was set before the click, 50 ms long, ours at the click, 100 ms, and
timers fire in the order they are due, however late.) By the same order, a
click after which nothing at all has left, looks after its throttle fired,
never reached the throttle or was thrown away with it: the button missed the
click, or the container holding the throttle was remounted, which cancels its
pending message (viser's ``useThrottledMessageSender``). That click is sent
after SILENT_LOOKS looks, unless its button is gone or disabled by then (a
busy fresh-clone run once lost 'Add account' so, for 15 s, with no message
after it). The worker is known from the first message the page sends after
this script runs; a page that has sent none since (its first messages left
before the script came) gets the click once more instead, through React's
handler and the throttle. A value may reach the server twice (harmless: the
same value). Not covered: number inputs and sliders (their values' types are
not in the DOM),
a dropdown chosen with the keyboard, and the code editor's hidden text area,
whose writes the editor resends itself (assets/editor-src/editor.js).
"""

from __future__ import annotations

import viser

from viewers.web.labels import script_image_html

# How long after a click to look, and how often, before giving up (ms): the
# throttle's timer fires 50 ms after the last send, later on a busy machine.
FIRST_LOOK_MS = 100
LOOK_EVERY_MS = 100
LOOKS = 100
# Looks with nothing at all sent since the click before it counts as lost (see above).
SILENT_LOOKS = 5

SURE_CLICKS_JS = """
(function () {
  if (window.__wartSureClicks) return;
  var state = window.__wartSureClicks = {clicks: 0, values: 0, lost: 0};
  var UUID = /^[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}$/;
  var GUI = /^Gui(Update|ButtonHold|FormSubmit|FormDirty)Message$/;
  var sent = [];
  var typed = {};
  var worker = null;
  var replaying = false;
  var post = Worker.prototype.postMessage;
  function update(w, uuid, value) {
    sent.push([performance.now(), uuid]);
    var message = {type: 'GuiUpdateMessage', uuid: uuid, updates: {value: value}};
    post.call(w, {type: 'send', message: message});
  }
  function flushTyped(w, leaving) {
    delete typed[leaving];
    for (var uuid in typed) {
      var t = typed[uuid];
      delete typed[uuid];
      if (!t[0].isConnected) continue;
      update(w, uuid, t[1] === 'check' ? t[0].checked : t[1] === 'choice' ? t[2] : t[0].value);
      state.values += 1;
    }
  }
  Worker.prototype.postMessage = function (data) {
    var m = data && data.type === 'send' ? data.message : null;
    if (m) worker = this;  /* the page's camera reports name it before any GUI message */
    if (m && GUI.test(m.type)) {
      flushTyped(this, m.uuid);
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
      flushTyped(worker, uuid);
      update(worker, uuid, true);
      state.clicks += 1;
      console.warn('wart: a click the message throttle dropped was sent again');
      return;
    }
    var button = document.getElementById(uuid);
    if (!other && LOOKS - left >= SILENT && button && !button.disabled) {
      state.lost += 1;
      if (worker) {
        flushTyped(worker, uuid);
        update(worker, uuid, true);
      } else {
        /* Nothing has left the page since this script came: click it once more,
           through React's handler and the throttle (ignored by the listener below). */
        replaying = true;
        try { button.click(); } finally { replaying = false; }
      }
      console.warn('wart: a click that never reached the message throttle was sent');
      return;
    }
    if (left > 0) setTimeout(function () { look(uuid, at, left - 1); }, EVERY);
  }
  function uuidOf(el) {
    if (UUID.test(el.id)) return el.id;
    var named = el.getAttribute('aria-labelledby') || '';
    if (named.indexOf('wart-label-') === 0 && UUID.test(named.slice(11))) return named.slice(11);
    for (var a = el.parentElement, i = 0; a && i < 6; a = a.parentElement, i++) {
      var prev = a.previousElementSibling;
      var label = prev && prev.querySelector('label[for]');
      if (label) return UUID.test(label.htmlFor) ? label.htmlFor : null;
    }
    return null;
  }
  document.addEventListener('input', function (e) {
    var el = e.target;
    if (!el || el.getAttribute('aria-hidden') === 'true') return;
    var text = el.tagName === 'TEXTAREA' || (el.tagName === 'INPUT' && !el.readOnly &&
      !el.inputMode && (el.type === 'text' || el.type === 'password'));
    var uuid = text && uuidOf(el);
    if (uuid) typed[uuid] = [el, 'text'];
  }, true);
  document.addEventListener('click', function (e) {
    var el = e.target;
    if (el && el.tagName === 'INPUT' && el.type === 'checkbox' && UUID.test(el.id)) {
      typed[el.id] = [el, 'check'];
      return;
    }
    var option = el && el.closest ? el.closest('[role=option][value]') : null;
    if (option) {
      var box = document.querySelector('input[role=combobox][aria-expanded=true]');
      if (box && UUID.test(box.id)) typed[box.id] = [box, 'choice', option.getAttribute('value')];
      return;
    }
    var b = el && el.closest ? el.closest('button') : null;
    if (replaying || !b || b.disabled || !UUID.test(b.id)) return;
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
        .replace("SILENT", str(SILENT_LOOKS))
    )
    return script_image_html(script)


def add_sure_clicks(gui: viser.GuiApi) -> viser.GuiHtmlHandle:
    """Make this page's clicks and typed values reach the server (once a page; more is harmless)."""
    return gui.add_html(sure_clicks_html())
