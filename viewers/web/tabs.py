"""Showing a tab from the server, and tab names a person can read.

viser 1.1.1 has no call that makes a tab the active one: the browser's tab
group keeps the tab its user last clicked, so after "Log in" or "Join" the
page stayed where it was and a notice named the new tab. The page can do it
itself: as in labels.py, an ``add_html`` image that cannot load runs its
``onerror``; here the script finds the tab (``role=tab``) whose text is the
tab's label and presses it as a person would (pointer down and up, then a
click: viser's dock tabs did not answer a bare ``click()``), and gives it a ``title``
(shown on hover) with the tab's full name. It retries for 5 s, because the tab
may be drawn just after the script. One element per page is reused: each
request rewrites its content (with a sequence number, so React replaces the
image and the handler runs again). Labels go into the script as JSON, escaped
for the attribute; nothing else of users' text is in it.
"""

from __future__ import annotations

import html
import ipaddress
import itertools
import json

import viser

from common.client.lab_address import LabAddress

SHOW_TAB_JS = """
(function (label, title, seq) {
  var tries = 0;
  function go() {
    var tabs = Array.prototype.filter.call(
      document.querySelectorAll('[role=tab]'),
      function (t) { return t.textContent.trim() === label; });
    var tab = tabs[tabs.length - 1];
    if (!tab) { if (++tries < 50) setTimeout(go, 100); return; }
    if (title) tab.title = title;
    if (tab.getAttribute('aria-selected') === 'true') return;
    var opts = { bubbles: true, cancelable: true, button: 0, isPrimary: true };
    tab.dispatchEvent(new PointerEvent('pointerdown', opts));
    tab.dispatchEvent(new MouseEvent('mousedown', opts));
    tab.dispatchEvent(new PointerEvent('pointerup', opts));
    tab.dispatchEvent(new MouseEvent('mouseup', opts));
    tab.click();
  }
  go();
})(LABEL, TITLE, SEQ);
"""


def tab_label(address: LabAddress) -> str:
    """A lab's tab name: ``realm@host``, a host name cut to its first part, no port.

    ``lab.physics.example.org:7447/walk`` reads ``walk@lab``; an IP address is
    kept whole (its first part says nothing). The full name is on hover
    (:func:`tab_title`).
    """
    host = address.host
    try:
        ipaddress.ip_address(host)
    except ValueError:
        host = host.split(".", 1)[0]
    return f"{address.realm}@{host}"


def tab_title(address: LabAddress) -> str:
    """A lab's full name, for hovering over its tab: ``realm at host:port``."""
    host = f"[{address.host}]" if ":" in address.host else address.host
    return f"{address.realm} at {host}:{address.port}"


def show_tab_html(label: str, title: str, seq: int) -> str:
    script = (
        SHOW_TAB_JS.replace("LABEL", json.dumps(label))
        .replace("TITLE", json.dumps(title))
        .replace("SEQ", str(seq))
    )
    script = " ".join(line.strip() for line in script.strip().splitlines())
    return (
        f'<img src="data:," alt="" data-seq="{seq}" style="display:none" '
        f'onerror="{html.escape(script, quote=True)}">'
    )


class TabSwitcher:
    """Makes a tab the active one in this browser (call from the page's GUI root)."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._seq = itertools.count(1)
        self._element = gui.add_html("")

    def show(self, label: str, title: str = "") -> None:
        self._element.content = show_tab_html(label, title, next(self._seq))


def page_title_html(title: str, seq: int) -> str:
    """An element that names the browser's tab (viser's page is titled "Viser")."""
    script = f"document.title={json.dumps(title)}"
    return (
        f'<img src="data:," alt="" data-seq="{seq}" style="display:none" '
        f'onerror="{html.escape(script, quote=True)}">'
    )


class PageTitle:
    """The browser tab's title: the lab logged in to last, or the viewer's name."""

    def __init__(self, gui: viser.GuiApi, title: str) -> None:
        self._seq = itertools.count(1)
        self._element = gui.add_html(page_title_html(title, 0))

    def set(self, title: str) -> None:
        self._element.content = page_title_html(title, next(self._seq))
