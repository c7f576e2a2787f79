"""Accessible names for viser's inputs: each labelled input gets ``aria-labelledby``.

viser 1.1.1 draws a GUI input's label as ``<label for="<element id>">`` but
gives the input itself an id of Mantine's making (text inputs, text areas,
number inputs and dropdowns; its checkboxes do carry the element id), so the
label names nothing: screen readers read the inputs unnamed, and Playwright's
``get_by_label`` does not find them. Neither the label's ``for`` nor the
input's attributes can be set from Python, CSS cannot give a name, and a
``<script>`` in ``add_html`` content never runs (it is inserted as
``innerHTML``).

An event handler attribute in that content does run, though: viser's HTML
element inserts its markup as is (React's ``dangerouslySetInnerHTML``, the
same property viewers/web/masked.py relies on), so an ``<img>`` that cannot
load runs its ``onerror``. :func:`add_label_fixer` adds one such element per
page. Its script, fixed text with nothing from users in it, watches the
page's DOM (added and removed nodes only, never the 25 Hz style changes of
scene labels) and, for every ``label[for]`` whose id names no element, gives
the label an id and the first input or text area in the box beside it (the
layout masked.py relies on too) ``aria-labelledby`` pointing at it. React
leaves both attributes alone (it sets neither), and a re-mounted input is
named again on the next change. Nothing is moved, restyled or renamed, so a
later viser that links its labels itself makes this a no-op; one that
sanitises HTML makes it inert, and inputs are then unnamed again but still
reachable by Tab beside their visible labels.
"""

from __future__ import annotations

import html
import re

import viser

# Runs once per page (window.__wartLabels); at most one pass per 50 ms of changes.
LABEL_FIX_JS = """
(function () {
  if (window.__wartLabels) return;
  window.__wartLabels = true;
  var pending = false;
  function fix() {
    pending = false;
    document.querySelectorAll("label[for]").forEach(function (label) {
      var target = label.htmlFor;
      if (!target || document.getElementById(target)) return;
      var own = label.parentElement && label.parentElement.parentElement;
      var box = own && own.nextElementSibling;
      var input = box && box.querySelector("input:not([type=hidden]), textarea");
      if (!input) return;
      if (!label.id) label.id = "wart-label-" + target;
      if (input.getAttribute("aria-labelledby") !== label.id) {
        input.setAttribute("aria-labelledby", label.id);
      }
    });
  }
  function later() {
    if (!pending) { pending = true; setTimeout(fix, 50); }
  }
  new MutationObserver(later).observe(document.body, { childList: true, subtree: true });
  fix();
})();
"""


def script_image_html(script: str) -> str:
    """An image that cannot load (an empty data URL) and runs ``script``, fixed text, once.

    The script goes in as one line: a ``//`` comment would end it there, so it is refused.
    """
    lines = [line.strip() for line in script.strip().splitlines()]
    commented = [line for line in lines if re.search(r"(^|\s)//", line)]
    if commented:
        raise ValueError(f"a // comment in a one-line script (use /* */): {commented[0]!r}")
    script = " ".join(lines)
    return (
        '<img src="data:," alt="" style="display:none" '
        f'onerror="{html.escape(script, quote=True)}">'
    )


def label_fixer_html() -> str:
    """The markup: an image that cannot load and runs the script."""
    return script_image_html(LABEL_FIX_JS)


def add_label_fixer(gui: viser.GuiApi) -> viser.GuiHtmlHandle:
    """Name every labelled input of this page (call once per client; more is harmless)."""
    return gui.add_html(label_fixer_html())
