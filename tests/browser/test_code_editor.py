"""The workbench's code editor (CodeMirror) in Chromium, against the demo lab.

Typed as a student types (Tab and Shift-Tab indent by four spaces, Enter
auto-indents); the text reaches the server; Ctrl-Enter checks and the planted
line is marked in the gutter with the message on hover; Ctrl-S saves; a file
opened on the server appears in the editor; a problem's line link moves the
cursor there. Every assertion reads the DOM or the server, never pixels.
"""

from __future__ import annotations

from tests.browser.conftest import ViserPage, join_demo_arena, wait_until
from viewers.web.app import WebViewer
from viewers.web.client import BrowserSession
from viewers.web.code_editor import show_text
from viewers.web.workbench import Workbench

TYPED = """\
from common.controller import Controller, Khepera


class Circle(Controller):
    period = 0.05

    def initialize(self, robot: Khepera) -> None:
        print("left_speed=[3, 4] *fast* #1 <b>x</b>")

    def do_work(self, robot: Khepera) -> None:
        robot.set_speed(8, 4)
"""


def workbench_of(session: BrowserSession) -> Workbench:
    wait_until(lambda: any(lab.panels for lab in session.labs.values()), what="the arena's panel")
    panel = next(tab for lab in session.labs.values() for tab in lab.panels.values())
    assert panel.workbench is not None
    return panel.workbench


def editor(page: ViserPage):
    return page.p.get_by_role("textbox", name="Controller code", exact=True)


def type_as_a_student(page: ViserPage) -> None:
    """Each line without its indent: Enter auto-indents, Tab and Shift-Tab adjust it."""
    kb = page.p.keyboard
    steps: list[tuple[str, str]] = [
        ("from common.controller import Controller, Khepera", "Enter"),
        ("", "Enter"),
        ("", "Enter"),
        ("class Circle(Controller):", "Enter"),  # auto-indent: 4 spaces
        ("period = 0.05", "Enter"),
        ("", "Enter"),
        ("def initialize(self, robot: Khepera) -> None:", "Enter"),  # 8 spaces
        ('print("left_speed=[3, 4] *fast* #1 <b>x</b>', "Enter"),  # ") closed by the editor
        ("", "Shift+Tab"),  # back to 4
        ("", "Enter"),
        ("def do_work(self, robot: Khepera) -> None:", "Enter"),
        ("robot.set_speed(8, 4", "Enter"),
    ]
    for text, key in steps:
        if text:
            kb.type(text)
        if text.startswith('print("') or text.startswith("robot.set_speed("):
            kb.press("End")  # past what the editor closed: ") or )
        kb.press(key)


def test_type_check_mark_save_open_and_jump(open_page, viewer: WebViewer) -> None:
    page, session = join_demo_arena(open_page, viewer, "ana")
    page.tab("arena").last.click()
    box = editor(page)
    box.wait_for(timeout=15_000)
    bench = workbench_of(session)
    # The old text area is still what the server reads, but out of sight and of Tab.
    hidden = page.input_after_label("Code")
    assert hidden.evaluate("e => e.tagName === 'TEXTAREA' && e.tabIndex === -1")
    assert hidden.evaluate("e => e.offsetParent === null")  # drawn nowhere
    lines = page.p.locator(".cm-gutter.cm-lineNumbers .cm-gutterElement")

    # At 1280x800 the editor is at least 12 lines tall, leaving the run's output below it in
    # view (test_layout.py); a student drags its corner for more.
    # Measured once laid out: right after the tab shows, the editor can still be 0 tall
    # (seen in a CI run); what the DOM says then is "not laid out yet", not "too small".
    def lines_tall() -> float:
        height = box.evaluate("el => el.closest('.cm-editor').getBoundingClientRect().height")
        line = box.evaluate("el => el.querySelector('.cm-line').getBoundingClientRect().height")
        return float(height) / float(line) if line else 0.0

    wait_until(lambda: lines_tall() >= 12, 10, what="the editor laid out 12 lines tall or more")
    assert box.evaluate("el => getComputedStyle(el.closest('.cm-editor')).resize") == "vertical"

    box.click()
    page.p.keyboard.press("Control+a")
    page.p.keyboard.press("Delete")
    wait_until(lambda: bench.code.value == "", what="the emptied editor on the server")
    type_as_a_student(page)
    # Trailing whitespace of the last Enter is the only difference from TYPED.
    wait_until(
        lambda: bench.code.value.rstrip(" ") == TYPED,
        15,
        what="the typed controller on the server",
    )
    assert lines.count() >= 12

    # Tab indents the current line by four spaces, Shift-Tab takes them back.
    page.p.keyboard.press("Control+Home")
    page.p.keyboard.press("Tab")
    wait_until(lambda: bench.code.value.startswith("    from common"), what="Tab's indent")
    page.p.keyboard.press("Shift+Tab")
    wait_until(lambda: bench.code.value.startswith("from common"), what="Shift-Tab's dedent")

    # The keyboard can leave the editor: Escape, then Tab moves on (Tab alone indents).
    page.p.keyboard.press("Escape")
    page.p.keyboard.press("Tab")
    assert not box.evaluate("el => el.contains(document.activeElement)")
    assert bench.code.value.startswith("from common")  # that Tab indented nothing
    box.click()

    # Ctrl-Enter checks: line 11 is marked in the gutter and in the text, message on hover.
    page.p.keyboard.press("Control+Enter")
    page.wait_text("Check found 1 problem")
    marker = page.p.locator(".cm-lint-marker-error")
    marker.wait_for(timeout=10_000)
    assert marker.count() == 1
    marked = page.p.evaluate(
        "() => [...document.querySelectorAll('.cm-content .cm-line')]"
        ".findIndex(l => l.querySelector('.cm-lintRange-error')) + 1"
    )
    assert marked == 11
    marker.hover()
    tip = page.p.locator(".cm-tooltip-lint")
    tip.wait_for(timeout=5_000)
    assert "does not exist on Khepera" in tip.inner_text()
    page.screenshot("editor-check-marks-line-11")

    # The problem's line number is a link: it puts the editor's cursor on line 11.
    box.click()
    page.p.keyboard.press("Control+Home")
    page.p.locator("a[data-wart-line='11']").click()

    def cursor_line() -> int:
        # The editor in sight: a view React replaced stays listed until the next poll.
        return int(
            page.p.evaluate(
                "() => { const v = window.wartEditor.editorFor(null).view;"
                " return v.state.doc.lineAt(v.state.selection.main.head).number; }"
            )
        )

    def editors() -> str:
        return str(
            page.p.evaluate(
                "() => [...window.wartEditor.views.values()].map(e => ({connected:"
                " e.view.dom.isConnected, shown: e.view.dom.offsetParent !== null, line:"
                " e.view.state.doc.lineAt(e.view.state.selection.main.head).number}))"
            )
        )

    wait_until(lambda: cursor_line() == 11, what=lambda: f"the cursor on line 11: {editors()}")

    # The server's copy of the text arriving late and a little different (a busy page)
    # changes only what differs: the cursor stays on line 11 (it went to line 1).
    # Each time the server and the page end up with the same text, even when the page's
    # own resend of the older text crosses the server's on the way (the server then held
    # the old text while the page showed the new).
    text = bench.code.value
    kept = text.rstrip("\n") + "\n# kept by the server\n"
    show_text(bench.code, kept)
    wait_until(lambda: "# kept by the server" in box.inner_text(), what="the server's text")
    assert cursor_line() == 11
    wait_until(lambda: bench.code.value == kept, what="the server's text kept at the server")
    show_text(bench.code, text)
    wait_until(lambda: "# kept by the server" not in box.inner_text(), what="the text back")
    wait_until(lambda: bench.code.value == text, what="the text back at the server")

    # Ctrl-S saves under the file name: the lab keeps it, the list shows it.
    page.p.keyboard.press("Control+s")
    wait_until(lambda: "mine: my_controller.py" in bench.start_from.options, what="the saved file")

    # A file the server opens appears in the editor.
    bench.start_from.value = next(o for o in bench.start_from.options if o.startswith("example"))
    example = bench._examples[bench.start_from.value.removeprefix("example: ")]
    page.click("Open")
    wait_until(
        lambda: (
            box.evaluate("el => el.cmView ? '' : el.innerText").strip()[:40]
            == example.decode().strip()[:40]
        ),
        10,
        what="the opened example in the editor",
    )
    assert page.p.locator(".cm-lint-marker-error").count() == 0


def test_typing_goes_on_when_the_page_redraws_the_editor(open_page, viewer: WebViewer) -> None:
    """A busy page can draw the editor's box anew while the student types (React re-creates
    it): the keys that follow land in the new editor, at the same place, and the whole text
    reaches the server. Redrawn here on purpose, between two halves of a line."""
    page, session = join_demo_arena(open_page, viewer, "ana")
    page.tab("arena").last.click()
    box = editor(page)
    box.wait_for(timeout=15_000)
    bench = workbench_of(session)
    box.click()
    page.p.keyboard.press("Control+a")
    page.p.keyboard.type("# first half, ")
    redrawn = page.p.evaluate(
        """() => {
            const host = document.querySelector('div.wart-editor[data-for]');
            const fresh = host.cloneNode(false);  // as React draws it: attributes, no editor
            delete fresh.dataset.mounted;
            host.replaceWith(fresh);
            return !fresh.isConnected ? 'not drawn' : 'drawn';
        }"""
    )
    assert redrawn == "drawn"
    page.p.keyboard.type("second half")
    text = "# first half, second half"
    wait_until(lambda: bench.code.value == text, what="the whole line on the server")
    assert editor(page).evaluate("e => e.textContent") == text
    assert page.p.locator("div.wart-editor .cm-editor").count() == 1  # the old one is gone
