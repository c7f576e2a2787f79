"""The book of pages a stopping viewer handed over (viewers/web/handover.py)."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import pytest

from viewers.web.handover import (
    HANDOVER_FILE,
    MAX_EDITOR_CHARS,
    EditorText,
    HandedOver,
    HandOverBook,
)

TOKEN = b"\x07" * 48


def page(user: str = "alice", *contexts: str, watching: str | None = None) -> HandedOver:
    return HandedOver(user, contexts or ("lobby", "arena"), watching, time.time())


def test_the_next_viewer_reopens_a_page_once_and_the_file_holds_no_token(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    book = HandOverBook(path)
    book.keep(TOKEN, page(watching="arena"))
    book.save()
    assert path.stat().st_mode & 0o777 == 0o600
    assert TOKEN.hex() not in path.read_text()  # a name for the login, not the login
    after = HandOverBook(path)  # the next process
    assert after.take(TOKEN, "bob") is None  # someone else's saved login: nothing
    assert HandOverBook(path).take(TOKEN, "alice") is None  # taken (and dropped) just above
    book.keep(TOKEN, page(watching="arena"))
    book.save()
    back = HandOverBook(path).take(TOKEN, "alice")
    assert back is not None and back.contexts == ("lobby", "arena") and back.watching == "arena"
    assert HandOverBook(path).take(TOKEN, "alice") is None  # good once


def test_a_page_back_too_late_starts_in_the_lobby(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    book = HandOverBook(path)
    book.keep(TOKEN, HandedOver("alice", ("arena",), None, time.time() - 7200))
    book.save()
    assert HandOverBook(path, max_age_s=3600).take(TOKEN, "alice") is None
    # Nor one stamped in the future (a hand-written file): it would never grow old.
    for at in (time.time() + 86400, float("inf"), float("nan")):
        book.keep(TOKEN, HandedOver("alice", ("arena",), None, at))
        book.save()
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
    book.keep(TOKEN, page("alice", "x y"))  # and not noted from a page either
    assert book.take(TOKEN, "alice") is None


def test_an_arenas_unsaved_editor_text_comes_back_bounded_and_as_text(tmp_path: Path) -> None:
    path = tmp_path / HANDOVER_FILE
    code = "class Mine(Controller):\n    pass  # not saved yet\n"
    editor = EditorText("arena", "mine.py", code, "k3")
    book = HandOverBook(path)
    book.keep(TOKEN, HandedOver("alice", ("lobby", "arena"), "arena", time.time(), (editor,)))
    book.save()
    back = HandOverBook(path).take(TOKEN, "alice")
    assert back is not None and back.editor("arena") == editor and back.editor("lobby") is None
    for bad in (
        EditorText("other", "mine.py", code, "k3"),  # a context the page had not joined
        EditorText("arena", "mine.py", "x" * (MAX_EDITOR_CHARS + 1), "k3"),
        EditorText("arena", "mine\x1b[2J.py", code, "k3"),
    ):
        fresh = HandOverBook(tmp_path / "another.json")
        fresh.keep(TOKEN, HandedOver("alice", ("arena",), None, time.time(), (bad,)))
        assert fresh.take(TOKEN, "alice") is None
