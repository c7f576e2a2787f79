"""The network page of a lab's tab, for admins: what `wart doctor` says, in the browser.

Routers and their links with round-trip times, every live service by kind,
each host's load, and what looks wrong in plain words (common/client/survey.py, the
same code the doctor prints). It is read with the viewer's own Zenoh session
on demand (a button), never on a timer: a survey queries every router.
"""

from __future__ import annotations

import logging
import math
import threading

import viser

from common.client.survey import Survey
from viewers.web.adapters import LabConnection, LabError
from viewers.web.text import escape_md

log = logging.getLogger("wart.viewer.network")


def format_survey(result: Survey) -> str:
    lines = [f"**Realm {escape_md(result.realm)}** (surveyed in {result.took_ms:.0f} ms)", ""]
    if result.problems:
        lines += ["**Problems**", ""] + [f"- ✗ {escape_md(p)}" for p in result.problems] + [""]
    else:
        lines += ["✓ no problem found", ""]
    lines += ["| router | round trip | links to | clients |", "| --- | --- | --- | --- |"]
    for r in result.routers:
        rtt = "no answer" if math.isnan(r.rtt_ms) else f"{r.rtt_ms:.1f} ms"
        links = ", ".join(escape_md(p) for p in r.peers) or "-"
        lines.append(f"| {escape_md(r.name)} | {rtt} | {links} | {r.clients} |")
    if not result.routers:
        lines.append("| (not visible to the viewer) | | | |")
    lines += ["", "| service | alive |", "| --- | --- |"]
    for kind, ids in result.alive.items():
        lines.append(f"| {escape_md(kind)} | {', '.join(escape_md(i) for i in ids)} |")
    if result.hosts:
        lines += [
            "",
            "| host | CPU | free memory | arenas | new arenas |",
            "| --- | --- | --- | --- | --- |",
        ]
        for load in result.hosts:
            arenas = ", ".join(escape_md(a.world) for a in load.arenas) or "-"
            state = "yes" if load.accepting else f"no: {escape_md(load.reason)}"
            lines.append(
                f"| {escape_md(load.host)} | {load.cpu_percent:.0f} % of {load.cpus} | "
                f"{load.mem_available_mb:.0f} MB | {arenas} | {state} |"
            )
    if result.notes:
        lines += [""] + [f"- {escape_md(n)}" for n in result.notes]
    return "\n".join(lines)


class NetworkPanel:
    """A folder with a Refresh button and the latest survey (admins only)."""

    def __init__(self, client: viser.ClientHandle, connection: LabConnection) -> None:
        self.client = client
        self.connection = connection
        self._busy = threading.Lock()
        gui = client.gui
        with gui.add_folder("Network (doctor)", expand_by_default=False):
            self.refresh = gui.add_button("Survey the lab")
            self.output = gui.add_markdown("_Press the button to survey routers and services._")
        self.refresh.on_click(lambda _: self.run())

    def run(self) -> None:
        if not self._busy.acquire(blocking=False):
            return  # a survey is already under way
        try:
            self.refresh.disabled = True
            self.output.content = "_Surveying..._"
            self.output.content = format_survey(self.connection.survey())
        except LabError as exc:
            self.output.content = f"**Could not survey the lab:** {escape_md(str(exc))}"
        except Exception:
            log.exception("network survey failed")
            self.output.content = "**The survey failed**; see the viewer's log."
        finally:
            self.refresh.disabled = False
            self._busy.release()
