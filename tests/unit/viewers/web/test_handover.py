"""The book of what the viewer's pages have open, for the next viewer (viewers/web/handover.py):
written as they change, so that a crash leaves it as well as a stop."""

from __future__ import annotations

import errno
import json
import logging
import time
from pathlib import Path

import pytest

from tests.kit.waits import wait_for
from viewers.web import handover
from viewers.web.handover import (
    HANDOVER_FILE,
    MAX_EDITOR_CHARS,
    MAX_PRINTED_CHARS,
    EditorText,
    HandedOver,
    HandOverBook,
    PageJournal,
)
from viewers.web.run_output import RUN_OUTPUT_LINES, RunOutput, as_html, as_text
from viewers.web.workbench import BenchMemory

TOKEN = b"\x07" * 48


def page(user: str = "alice", *contexts: str, watching: str | None = None) -> HandedOver:
    return HandedOver(user, contexts or ("lobby", "arena"), watching, time.time())


def test_the_next_viewer_reopens_a_page_once_and_the_file_holds_no_token(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    assert HandOverBook(path).note_open([(TOKEN, page(watching="arena"))])
    assert path.stat().st_mode & 0o777 == 0o600
    assert TOKEN.hex() not in path.read_text()  # a name for the login, not the login
    after = HandOverBook(path)  # the next process
    assert after.take(TOKEN, "bob") is None  # someone else's saved login: nothing
    assert HandOverBook(path).take(TOKEN, "alice") is None  # taken (and dropped) just above
    assert HandOverBook(path).note_open([(TOKEN, page(watching="arena"))])
    back = HandOverBook(path).take(TOKEN, "alice")
    assert back is not None and back.contexts == ("lobby", "arena") and back.watching == "arena"
    assert HandOverBook(path).take(TOKEN, "alice") is None  # good once


def test_a_page_back_too_late_starts_in_the_lobby(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    book = HandOverBook(path)
    book.note_open([(TOKEN, HandedOver("alice", ("arena",), None, time.time() - 7200))])
    assert HandOverBook.name(TOKEN) in path.read_text()
    assert HandOverBook(path, max_age_s=3600).take(TOKEN, "alice") is None
    # Nor one stamped in the future (a hand-written file): it would never grow old.
    for at in (time.time() + 86400, float("inf"), float("nan")):
        book.note_open([(TOKEN, HandedOver("alice", ("arena",), None, at))])
        assert HandOverBook(path).take(TOKEN, "alice") is None
    assert HandOverBook.name(TOKEN) not in path.read_text()  # gone from the file at start


@pytest.mark.parametrize(
    "content",
    [b"{not json", b'["a list"]', b'{"' + b"a" * 64 + b'": {"user": 3}}', b"\xff\xfe"],
)
def test_an_unreadable_file_is_set_aside_and_the_viewer_starts(
    tmp_path: Path, content: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / HANDOVER_FILE
    path.write_bytes(content)
    with caplog.at_level(logging.WARNING, logger="wart.viewer.handover"):
        book = HandOverBook(path)
    assert book.take(TOKEN, "alice") is None
    assert "could not be read" in caplog.text and "come back to their lab's lobby" in caplog.text
    assert (tmp_path / (HANDOVER_FILE + ".unreadable")).read_bytes() == content


def test_names_that_are_not_contexts_never_reach_a_join(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    name = HandOverBook.name(TOKEN)
    # Written by hand (or by something else): a context named like a key expression.
    entry = {"user": "alice", "contexts": ["lobby", "a/**"], "watching": None, "at": time.time()}
    path.write_text(json.dumps({name: entry}))
    assert HandOverBook(path).take(TOKEN, "alice") is None
    book = HandOverBook(path)
    book.note_open([(TOKEN, page("alice", "x y"))])  # and not noted from a page either
    assert HandOverBook(path).take(TOKEN, "alice") is None
    assert "x y" not in path.read_text()


def test_an_arenas_unsaved_editor_text_comes_back_bounded_and_as_text(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    code = "class Mine(Controller):\n    pass  # not saved yet\n"
    editor = EditorText("arena", "mine.py", code, "k3")
    book = HandOverBook(path)
    book.note_open(
        [(TOKEN, HandedOver("alice", ("lobby", "arena"), "arena", time.time(), (editor,)))]
    )
    back = HandOverBook(path).take(TOKEN, "alice")
    assert back is not None and back.editor("arena") == editor and back.editor("lobby") is None
    for bad in (
        EditorText("other", "mine.py", code, "k3"),  # a context the page had not joined
        EditorText("arena", "mine.py", "x" * (MAX_EDITOR_CHARS + 1), "k3"),
        EditorText("arena", "mine\x1b[2J.py", code, "k3"),
    ):
        another = tmp_path / "another.json"
        HandOverBook(another).note_open(
            [(TOKEN, HandedOver("alice", ("arena",), None, time.time(), (bad,)))]
        )
        assert HandOverBook(another).take(TOKEN, "alice") is None


def editing(code: str, user: str = "alice") -> HandedOver:
    """A page in its arena, its editor holding ``code``."""
    editor = EditorText("arena", "mine.py", code, "k3")
    return HandedOver(user, ("lobby", "arena"), "arena", time.time(), (editor,))


def test_a_viewer_that_crashes_leaves_its_pages_as_last_noted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Nothing is written at a crash: the next viewer reads the journal's last note."""
    path = tmp_path / HANDOVER_FILE
    open_now = [(TOKEN, editing("v1"))]
    journal = PageJournal(HandOverBook(path), lambda: open_now, period_s=0.02)
    journal.start()
    wait_for(lambda: path.exists() and '"v1"' in path.read_text(), 10, "the first note")
    open_now = [(TOKEN, editing("v2: typed since"))]
    wait_for(lambda: "v2: typed since" in path.read_text(), 10, "the editor's change noted")
    journal.stop()  # the process is gone: what it noted last is all there is
    open_now = [(TOKEN, editing("v3: never noted"))]
    time.sleep(0.1)
    with caplog.at_level(logging.INFO, logger="wart.viewer.handover"):
        book = HandOverBook(path)  # the next viewer says what it found
    assert "the tabs of 1 page(s) kept by the last viewer here" in caplog.text
    back = book.take(TOKEN, "alice")
    assert back is not None and back.watching == "arena"
    assert back.editor("arena") == EditorText("arena", "mine.py", "v2: typed since", "k3")


def test_the_journal_writes_when_a_page_changes_and_forgets_a_page_that_went(
    tmp_path: Path,
) -> None:
    path = tmp_path / HANDOVER_FILE
    book = HandOverBook(path)
    assert book.note_open([(TOKEN, editing("x = 1"))])
    written = path.read_bytes()
    assert not book.note_open([(TOKEN, editing("x = 1"))])  # the same page, later: not again
    assert path.read_bytes() == written
    assert book.note_open([(TOKEN, editing("x = 2"))])
    assert book.note_open([])  # logged out (or its session ended): not for the next viewer
    assert HandOverBook.name(TOKEN) not in path.read_text()
    assert HandOverBook(path).take(TOKEN, "alice") is None


def test_the_last_viewers_pages_not_yet_back_stay_beside_this_ones(tmp_path: Path) -> None:
    """After a restart the pages come back one by one: the ones still away keep their
    entry while the journal notes those already back, until each takes its own."""
    path = tmp_path / HANDOVER_FILE
    away, back = b"\x01" * 48, b"\x02" * 48
    HandOverBook(path).note_open([(away, editing("alice's")), (back, editing("bob's", "bob"))])
    book = HandOverBook(path)  # the next viewer
    assert book.take(back, "bob") is not None
    book.note_open([(b"\x03" * 48, editing("bob's, on the new viewer", "bob"))])
    again = HandOverBook(path)  # and the one after it (a second restart)
    alice = again.take(away, "alice")
    assert alice is not None and alice.editor("arena") is not None
    bob = again.take(b"\x03" * 48, "bob")
    assert bob is not None and bob.editors[0].code == "bob's, on the new viewer"
    assert again.take(back, "bob") is None  # taken once already, and bob has no other


def test_two_tabs_sharing_one_cookie_each_get_one_of_their_pages(tmp_path: Path) -> None:
    """Both tabs come back with the saved login the last of them stored: one takes its
    page by that name, the other (reloaded for the login the first was given) the other."""
    path = tmp_path / HANDOVER_FILE
    first_tab, cookie = b"\x01" * 48, b"\x02" * 48  # the cookie: the second tab's login
    HandOverBook(path).note_open(
        [
            (first_tab, editing("tab one")),
            (cookie, editing("tab two")),
            (b"\x05" * 48, editing("bob's", "bob")),
        ]
    )
    book = HandOverBook(path)
    one = book.take(cookie, "alice")
    # A page bringing a login this viewer did not give takes nothing that is not its own...
    assert book.take(b"\x03" * 48, "alice") is None
    # ...but one bringing the login this viewer just gave the first tab takes the other.
    book.issued(b"\x03" * 48)
    other = book.take(b"\x03" * 48, "alice")
    assert one is not None and other is not None
    assert {one.editors[0].code, other.editors[0].code} == {"tab one", "tab two"}
    book.issued(b"\x04" * 48)
    assert book.take(b"\x04" * 48, "alice") is None  # no third page, and never bob's
    book.issued(b"\x06" * 48)
    assert book.take(b"\x06" * 48, "bob") is not None


def test_long_after_the_start_a_new_tab_opens_only_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tab opened an hour into the class is not given a page left at the restart."""
    path = tmp_path / HANDOVER_FILE
    HandOverBook(path).note_open([(b"\x01" * 48, editing("left at the restart"))])
    book = HandOverBook(path)
    book.issued(b"\x02" * 48)
    monkeypatch.setattr(handover, "SIBLING_WINDOW_S", -1.0)
    assert book.take(b"\x02" * 48, "alice") is None


class FakeHtml:
    content = ""


class FakeGui:
    def add_html(self, content: str) -> FakeHtml:
        return FakeHtml()


def test_the_runs_output_comes_back_as_text_escaped_again(tmp_path: Path) -> None:
    """What the controller printed, markup and all, is shown as printed after the restart:
    the file keeps plain text, never HTML the page would take as its own."""
    output = RunOutput(FakeGui())  # type: ignore[arg-type]
    output.note("running on k3")
    output.lines(["tick 1", "<i>not a note</i> & <script>alert(1)</script>"])
    bench = BenchMemory(
        "mine.py", "code", "k3", ("arena", "k3"), "", (), ((), ""), tuple(output.printed)
    )
    path = tmp_path / HANDOVER_FILE
    HandOverBook(path).note_open([(TOKEN, HandedOver.of("alice", [("arena", bench)], "arena"))])
    assert "<script>" in path.read_text() and "&lt;" not in path.read_text()  # plain text
    back = HandOverBook(path).take(TOKEN, "alice")
    assert back is not None
    editor = back.editor("arena")
    assert editor is not None and editor.printed_on == "k3"
    assert editor.printed == (
        ("running on k3", True),
        ("tick 1", False),
        ("<i>not a note</i> & <script>alert(1)</script>", False),
    )
    assert as_html(editor.printed) == tuple(output.printed)  # shown exactly as before
    assert as_text(as_html(editor.printed)) == editor.printed


@pytest.mark.parametrize(
    "printed, printed_on",
    [
        ((("x", False),) * (RUN_OUTPUT_LINES + 1), "k3"),
        ((("x" * (MAX_PRINTED_CHARS + 1), False),), "k3"),
        ((("tick 1", False),), "k3/**"),
    ],
)
def test_an_output_out_of_bounds_is_not_kept(
    tmp_path: Path, printed: tuple[tuple[str, bool], ...], printed_on: str
) -> None:
    path = tmp_path / HANDOVER_FILE
    editor = EditorText("arena", "mine.py", "code", "k3", printed, printed_on)
    HandOverBook(path).note_open(
        [(TOKEN, HandedOver("alice", ("arena",), None, time.time(), (editor,)))]
    )
    assert HandOverBook(path).take(TOKEN, "alice") is None


def test_a_book_that_cannot_be_written_says_so_once_and_again_when_it_can(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / HANDOVER_FILE
    book = HandOverBook(path)

    def disk_full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(handover, "write_atomic", disk_full)
    with caplog.at_level(logging.INFO, logger="wart.viewer.handover"):
        for n in range(3):
            book.note_open([(TOKEN, editing(f"x = {n}"))])
    assert caplog.text.count("could not keep the pages' tabs") == 1
    assert "No space left" in caplog.text
    assert "come back to their lab's lobby (their runs go on)" in caplog.text
    monkeypatch.undo()
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="wart.viewer.handover"):
        book.note_open([(TOKEN, editing("x = 2"))])  # unchanged since: written all the same
    assert "kept for the next viewer" in caplog.text
    assert "x = 2" in path.read_text()
