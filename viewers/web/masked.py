"""Password inputs: viser text inputs made real ``<input type="password">`` in the page.

viser 1.1.1's text input has no password option. Its HTML element, though,
puts its markup in the page as is (React's ``dangerouslySetInnerHTML``, no
sanitising; labels.py relies on the same), so each password input gets an
``add_html`` element beside it holding two things, keyed on the input's
element id (viser draws its label as ``<label for="<id>">`` in a box beside
the input's box; the input itself gets another id from Mantine):

- an ``<img>`` that cannot load, whose ``onerror`` sets that one input's
  ``type`` attribute to ``password`` (so every browser masks it and password
  managers see a password field) and ``autocomplete``. React removes the
  ``type`` attribute again at every render (seen: the field became a text
  field at the first keystroke, still masked by the style rule below), so a
  MutationObserver on that attribute puts it back at once (its callback runs
  before the page is next drawn); another re-applies all this to an input
  viser re-mounts. With ``submit``, Enter in the input presses that
  button, 120 ms later: viser's page sends GUI messages through one 50 ms
  throttle that keeps only the newest, so an immediate press could replace
  the typed password's own message;
- a ``<style>`` rule, ``-webkit-text-security: disc`` on the same input, for
  the moment before the script has run (Chromium and WebKit honour it).

The typed text still reaches the viewer as every viser input does (over the
page's websocket); callers empty the field as soon as they have used it.
"""

from __future__ import annotations

import html
import json

import viser

MASK = "-webkit-text-security: disc !important;"
SUBMIT_DELAY_MS = 120

# viser's <input> of the GUI element with id ``id`` (its label's ``for``), for the page's
# scripts that read or write an input (here, drive_keys.py, front_tab.py): put in for INPUT_OF.
INPUT_OF_JS = """function input() {
    var label = document.querySelector('label[for="' + id + '"]');
    var own = label && label.parentElement && label.parentElement.parentElement;
    var box = own && own.nextElementSibling;
    return (box && box.querySelector('input')) || document.getElementById(id);
  }"""

# Fixed text; the element id and the button's label go in as JSON.
PASSWORD_JS = """
(function (id, submit, password) {
  INPUT_OF
  function fix() {
    var el = input();
    if (!el || el.dataset.wartPassword) return;
    el.dataset.wartPassword = '1';
    if (password) {
      el.setAttribute('type', 'password');
      el.autocomplete = 'current-password';
      /* React drops the type attribute again at every render; put it back at once (a
         mutation callback runs before the page is next drawn). */
      new MutationObserver(function () {
        if (el.getAttribute('type') !== 'password') el.setAttribute('type', 'password');
      }).observe(el, { attributes: true, attributeFilter: ['type'] });
    }
    if (!submit) return;
    el.addEventListener('keydown', function (e) {
      if (e.key !== 'Enter' || e.isComposing) return;
      e.preventDefault();
      setTimeout(function () {
        var buttons = document.querySelectorAll('button');
        for (var i = buttons.length - 1; i >= 0; i--) {
          if (buttons[i].textContent.trim() === submit && !buttons[i].disabled) {
            buttons[i].click();
            return;
          }
        }
      }, DELAY);
    });
  }
  fix();
  new MutationObserver(fix).observe(document.body, { childList: true, subtree: true });
})(ID, SUBMIT, PASSWORD);
"""


def _check_id(element_id: str) -> str:
    if not element_id or any(c in element_id for c in "\"'\\<>{}"):
        raise ValueError(f"not an element id: {element_id!r}")
    return element_id


def mask_rule(element_id: str) -> str:
    """The CSS that masks the text input labelled by ``<label for=element_id>``."""
    _check_id(element_id)
    beside = f'div:has(> * > label[for="{element_id}"]) + div'
    return (
        f"{beside} input, {beside} textarea {{ {MASK} }}\n"
        f'input[id="{element_id}"], textarea[id="{element_id}"] {{ {MASK} }}'
    )


def _script_html(element_id: str, submit: str | None, password: bool) -> str:
    script = (
        PASSWORD_JS.replace("INPUT_OF", INPUT_OF_JS)
        .replace("ID", json.dumps(_check_id(element_id)))
        .replace("SUBMIT", json.dumps(submit))
        .replace("PASSWORD", json.dumps(password))
        .replace("DELAY", str(SUBMIT_DELAY_MS))
    )
    script = " ".join(line.strip() for line in script.strip().splitlines())
    return f'<img src="data:," alt="" style="display:none" onerror="{html.escape(script)}">'


def password_html(element_id: str, submit: str | None = None) -> str:
    """The style rule and the image whose ``onerror`` makes the input a password input."""
    return f"<style>{mask_rule(element_id)}</style>" + _script_html(element_id, submit, True)


def add_submit_on_enter(gui: viser.GuiApi, handle: viser.GuiTextHandle, submit: str) -> None:
    """Enter in the text input ``handle`` presses the button labelled ``submit``."""
    gui.add_html(_script_html(element_id(handle), submit, False))


def element_id(handle: viser.GuiTextHandle) -> str:
    # viser 1.1.1 keeps a GUI element's id (its label's `for`) only on the handle's
    # private state; there is no public accessor.
    return str(handle._impl.uuid)


def add_masked_text(
    gui: viser.GuiApi, label: str, initial_value: str = "", *, submit: str | None = None
) -> viser.GuiTextHandle:
    """A password input (in the current container); Enter presses the button ``submit``."""
    handle = gui.add_text(label, initial_value)
    # An element that takes no room in the panel: a <style> and a hidden image.
    gui.add_html(password_html(element_id(handle), submit))
    return handle
