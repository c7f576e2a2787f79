"""A reload mid-run in Chromium against a real lab: the run and its slot go on, and the page
comes back with its arena tab, the editor's unsaved buffer, the chosen robot and the output;
a page gone for longer than the grace ends the run in words that say so.

Router, registry, engine, runner (bubblewrap sandboxes) and the agent context ``arena``,
as in test_workbench; slots long enough that only Stop or the grace ends a run. The last
two restart the viewer: stopped, as an upgrade does, and killed, as a crash does.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from services.lab.wiring import viewer_spec
from tests.browser.conftest import ViserPage, wait_until
from tests.browser.test_real_agents import choose, enter_arena
from tests.browser.test_real_lab import session_of
from tests.browser.test_workbench import write_code
from tests.conftest import needs_sandbox
from tests.kit.lab import PASSWORD
from tests.kit.procs import free_port
from tests.kit.reallab import RealLab, real_lab
from viewers.web.app import WebViewer
from viewers.web.chat_panel import ChatPanel
from viewers.web.connector import LiveConnector
from viewers.web.handover import HANDOVER_FILE
from viewers.web.tabs import tab_label

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

CTX = "arena"
TICKING = """\
from common.controller import Controller, Khepera


class Ticking(Controller):
    period = 0.05

    def initialize(self, robot: Khepera) -> None:
        self.ticks = 0

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(2, 2)
        self.ticks += 1
        if self.ticks % 20 == 0:
            print(f"tick {self.ticks // 20}")
"""
UNSAVED = TICKING + "# typed after Run, never saved\n"


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("reload")), agents=True, slot=600.0) as env:
        yield env


def ticks_shown(page: ViserPage) -> list[int]:
    """The tick numbers the page's output shows (what the student reads)."""
    text = " ".join(page.p.locator("pre.wart-output").all_inner_texts())
    return [int(n) for n in re.findall(r"tick (\d+)", text)]


def run_output(page: ViserPage) -> str:
    """The run's output under the editor, as the page shows it."""
    return " ".join(page.p.locator(".wart-run-output").all_inner_texts())


def start_ticking(page: ViserPage, panel: ChatPanel, agent: str) -> None:
    bench = panel.workbench
    assert bench is not None
    write_code(page, TICKING, lambda: bench.code.value == TICKING)
    choose(page, "Run on", agent)
    wait_until(lambda: bench.target.value == agent, 10, what=f"{agent} chosen to run on")
    page.click("Run in simulation")
    page.wait_text(f"Your controller runs on {agent}", timeout=30_000)
    wait_until(lambda: ticks_shown(page), 30, what="the controller's first print on the page")


def test_a_reload_mid_run_keeps_the_run_the_editor_and_the_output(open_page, lab: RealLab) -> None:
    alice = open_page("alice")
    panel = enter_arena(alice, lab, "alice")
    lab_tab = next(iter(session_of(lab.viewer, "alice").labs.values())).tab_name
    # The browser's tab names the lab (viser's own page says "Viser").
    wait_until(lambda: alice.p.title() == f"{lab_tab} · WART lab", 10, what="the page's title")
    start_ticking(alice, panel, "k0")
    bench = panel.workbench
    assert bench is not None
    write_code(alice, UNSAVED, lambda: bench.code.value == UNSAVED)
    before = max(ticks_shown(alice))
    old_connection = panel.connection

    alice.p.reload()
    alice.wait_ready()
    # No password, no Join: the arena's tab is in front again, on the same lab session.
    alice.wait_text("Your controller runs on k0", timeout=30_000)
    session = session_of(lab.viewer, "alice")
    tab = next(iter(session.labs.values()))
    assert tab.connection is old_connection  # the session was kept, not logged in again
    back = tab.panels[CTX]
    assert back is not panel and back.workbench is not None
    # The unsaved buffer, on the server and in the browser's editor.
    assert back.workbench.code.value == UNSAVED
    shown = alice.p.evaluate("() => window.wartEditor.editorFor(null).view.state.doc.toString()")
    assert shown == UNSAVED
    assert back.workbench.target.value == "k0"
    # The output so far is there, and the run prints on: it was never stopped.
    assert before in ticks_shown(alice)
    wait_until(lambda: max(ticks_shown(alice)) > before + 2, 30, what="new prints after reload")
    # What it printed while the page was away is there too (the context's count), once each.
    ticks = [int(n) for n in re.findall(r"\btick (\d+)\b", run_output(alice))]
    assert ticks == list(range(1, len(ticks) + 1)), ticks
    assert "cancelled" not in " ".join(alice.p.locator("pre.wart-output").all_inner_texts())
    assert back.robots is not None and back.robots.driven("k0")
    alice.screenshot("reload-kept-the-run")

    # And the restored page still drives it: Stop ends the run; Reset then puts k0 back.
    alice.click("Stop")
    alice.wait_text("Your controller on k0 cancelled", timeout=15_000)
    alice.click("Reset")
    alice.wait_text("Reset: k0 is back at", timeout=15_000)


def test_a_page_gone_longer_than_the_grace_ends_the_run_and_says_why(
    open_page, lab: RealLab
) -> None:
    grace = lab.viewer.parking.grace_s
    lab.viewer.parking.grace_s = 3.0
    try:
        bob = open_page("bob")
        bob_panel = enter_arena(bob, lab, "bob")
        alice = open_page("alice")
        panel = enter_arena(alice, lab, "alice")
        start_ticking(alice, panel, "k1")
        alice.p.close()  # the lid shut; nobody comes back within the grace
        # Bob, in the same arena, reads why alice's run ended.
        bob.wait_text(
            "alice's controller on k1 was cancelled: the page was closed for more than 3 s",
            timeout=30_000,
        )
        assert bob_panel.robots is not None
        wait_until(lambda: not bob_panel.robots.driven("k1"), 15, what="k1 free again")
    finally:
        lab.viewer.parking.grace_s = grace


def test_two_tabs_of_one_student_show_the_same_run_and_either_stops_it(
    open_page, lab: RealLab
) -> None:
    """A second tab (a second window, a phone) follows the run the first started, with what
    it printed before that tab opened; Stop there ends it, and both tabs say so."""
    first = open_page("first")
    panel = enter_arena(first, lab, "carol")
    start_ticking(first, panel, "k2")
    wait_until(lambda: "tick 1" in run_output(first), 30, "the first print in tab one")
    second = open_page("second")
    second.log_in(lab.url, "carol", PASSWORD)
    second.tab(tab_label(lab.address)).first.click()
    second.wait_text("Logged in as")
    second.click(f"Join {CTX}", timeout=15_000)
    second.tab(f"{CTX} (arena)").last.click()
    second.wait_text("Your controller runs on k2 (started in another tab or tool)", timeout=30_000)
    # The second tab's editor shows what the run printed before it opened (the context
    # keeps it), then the prints as they come, each once.
    wait_until(lambda: "following your run on k2" in run_output(second), 15, "the note")
    wait_until(lambda: "tick 1" in run_output(second), 30, "a print from before tab two")
    wait_until(lambda: "tick 3" in run_output(second), 30, "a print since")
    ticks = [int(n) for n in re.findall(r"\btick (\d+)\b", run_output(second))]
    assert ticks == list(range(1, len(ticks) + 1)), ticks  # from the first, none twice
    second.click("Stop")
    second.wait_text("Your controller on k2 cancelled", timeout=15_000)
    first.wait_text("Your controller on k2 cancelled", timeout=15_000)
    robots = panel.robots
    assert robots is not None
    wait_until(lambda: not robots.driven("k2"), 15, what="k2 free in the first tab")


def restart_viewer(lab: RealLab) -> None:
    """The viewer stopped as SIGTERM stops it (ViewerService.on_stop), and the next one
    started on its port and data directory, with a new connector as a new process has."""
    old, port = lab.viewer, lab.viewer.port
    data_dir = old.handovers.path.parent if old.handovers.path is not None else None
    assert data_dir is not None
    old.stop()
    lab.connector.close()
    lab.connector = LiveConnector(lab.session, lab.address, lab.lab.key_hex, data_dir=data_dir)
    lab.viewer = WebViewer(lab.connector, port=port, default_address=lab.address, data_dir=data_dir)


def test_a_viewer_restarted_mid_run_keeps_the_run_and_the_page_comes_back_to_its_arena(
    open_page, lab: RealLab
) -> None:
    """An upgrade or a supervisor's restart of the viewer: the session is handed over, not
    logged out. The run goes on, and the page, reconnecting by itself to the new viewer at
    the same address, logs in again by its saved login and opens its arena again, with the
    editor's unsaved text."""
    bob = open_page("bob-restart")
    panel = enter_arena(bob, lab, "bob")
    start_ticking(bob, panel, "k3")
    bench = panel.workbench
    assert bench is not None
    write_code(bob, UNSAVED, lambda: bench.code.value == UNSAVED)
    before = max(ticks_shown(bob))
    restart_viewer(lab)
    # No click: viser's page reconnects, the cookie logs it in, the arena opens in front.
    bob.wait_text("the web viewer restarted; your runs went on", timeout=60_000)
    bob.wait_text("Your controller runs on k3", timeout=30_000)
    back = next(iter(session_of(lab.viewer, "bob").labs.values())).panels[CTX]
    assert back.workbench is not None and back.robots is not None
    # The editor's text typed after Run and never saved, on the server and in the browser.
    assert back.workbench.code.value == UNSAVED and back.workbench.target.value == "k3"
    shown = bob.p.evaluate("() => window.wartEditor.editorFor(null).view.state.doc.toString()")
    assert shown == UNSAVED
    # The output from before the restart is still under the editor, and says what happened.
    assert before in ticks_shown(bob)
    bob.wait_text("the web viewer restarted here; your run went on")
    wait_until(lambda: back.robots is not None and back.robots.driven("k3"), 15, "k3 driven")
    # It was never stopped: the prints go on past those from before the restart.
    wait_until(lambda: max(ticks_shown(bob), default=0) > before + 2, 30, "prints go on")
    assert "cancelled" not in " ".join(bob.p.locator("pre.wart-output").all_inner_texts())
    bob.screenshot("viewer-restart-kept-the-run")
    bob.click("Stop")
    bob.wait_text("Your controller on k3 cancelled", timeout=15_000)


def editor_text(page: ViserPage) -> str:
    return page.p.evaluate("() => window.wartEditor.editorFor(null).view.state.doc.toString()")


def test_a_viewer_killed_mid_run_brings_the_page_back_to_its_arena_as_last_noted(
    open_page, lab: RealLab, tmp_path: Path
) -> None:
    """A crash (kill -9, the OOM killer, a node lost) writes nothing at its end. The viewer
    notes what its pages have open as they go (viewers/web/handover.py), so the next
    viewer process brings the page back to its arena, its run going on, and its editor
    as last noted."""
    spec = viewer_spec(lab.lab.wiring(), "crashing", http_port=free_port())
    argv = list(spec.argv)
    data_dir = tmp_path / "viewer"  # not the module viewer's: each keeps its own book
    argv[argv.index("--data-dir") + 1] = str(data_dir)
    spec = dataclasses.replace(spec, argv=argv)
    first = lab.lab.start(spec, name="viewer-first")
    url = f"http://127.0.0.1:{argv[argv.index('--http-port') + 1]}"
    carol = open_page("carol-crash")
    carol.open(url)
    carol.log_in(lab.url, "carol", PASSWORD)
    carol.tab(tab_label(lab.address)).first.click()
    carol.click(f"Join {CTX}", timeout=15_000)
    carol.tab(f"{CTX} (arena)").last.click()
    carol.wait_text("Upload controller")
    write_code(carol, TICKING, lambda: editor_text(carol) == TICKING)
    choose(carol, "Run on", "k1")
    carol.click("Run in simulation")
    carol.wait_text("Your controller runs on k1", timeout=30_000)
    wait_until(lambda: ticks_shown(carol), 30, what="the controller's first print on the page")
    noted = TICKING + "# typed after Run, never saved: noted by the viewer\n"
    write_code(carol, noted, lambda: editor_text(carol) == noted)
    book = data_dir / HANDOVER_FILE
    wait_until(
        lambda: book.exists() and "noted by the viewer" in book.read_text(),
        30,
        what="the page's editor noted in the viewer's book",
    )
    before = max(ticks_shown(carol))
    first.popen.kill()  # SIGKILL: no stop, no hand-over, nothing written
    first.popen.wait(10)
    lab.lab.start(spec, name="viewer-after-crash")
    # No click: the page reconnects, its cookie logs it in, its arena opens in front.
    carol.wait_text("the web viewer restarted; your runs went on", timeout=60_000)
    carol.wait_text("Your controller runs on k1", timeout=30_000)
    wait_until(lambda: editor_text(carol) == noted, 15, what="the editor's noted text back")
    assert 1 in ticks_shown(carol), "the output printed before the crash, as noted"
    # It was never stopped: the prints go on past those from before the crash.
    wait_until(lambda: max(ticks_shown(carol), default=0) > before + 2, 30, "prints go on")
    carol.screenshot("viewer-crash-kept-the-run")
    carol.click("Stop")
    carol.wait_text("Your controller on k1 cancelled", timeout=15_000)


def test_two_tabs_of_one_browser_both_come_back_to_the_arena_after_a_viewer_restart(
    open_page, lab: RealLab
) -> None:
    """Two tabs share the browser's cookie, so both come back with the one saved login it
    holds: the first to arrive uses it, and the second, refused as used, reloads to send
    the login the first was given, and opens its arena too (not the password form)."""
    one = open_page("ida-tab-one")
    enter_arena(one, lab, "ida")
    two = ViserPage(one.p.context.new_page(), "ida-tab-two")  # the same browser: one cookie
    two.open(lab.viewer.url)
    two.tab(tab_label(lab.address)).first.click()  # logged in by the cookie
    two.wait_text("Logged in as")
    two.click(f"Join {CTX}", timeout=15_000)
    two.tab(f"{CTX} (arena)").last.click()
    two.wait_text("Upload controller")
    restart_viewer(lab)
    # Each page says so for 5 s, each at its own time: both are watched at once.
    back: set[str] = set()

    def both_back() -> bool:
        for page in (one, two):
            text = page.p.inner_text("body")
            if (
                "the web viewer restarted; your runs went on" in text
                and "Upload controller" in text
            ):
                back.add(page.name)
        return len(back) == 2

    wait_until(both_back, 60, what="both tabs back in their arena")
    assert len([s for s in lab.viewer.sessions.values() if s.labs]) == 2
