"""My run's output under the editor: what the controller printed, and the exceptions in it."""

from __future__ import annotations

import html
from collections import deque
from collections.abc import Iterable

import viser

from common.controller.advice import Problem
from viewers.web.marks import TracebackReader
from viewers.web.text import output_html, printed

RUN_OUTPUT_LINES = 200  # the run's last printed lines under the editor
_NOTE_OPEN, _NOTE_CLOSE = "<i>", "</i>"


def as_text(lines: Iterable[str]) -> tuple[tuple[str, bool], ...]:
    """The lines under the editor as plain text, each with whether it is the lab's note
    (for a file the next viewer reads: no HTML is kept, it is made again on the way in)."""
    texts = []
    for line in lines:
        note = line.startswith(_NOTE_OPEN) and line.endswith(_NOTE_CLOSE)
        inner = line[len(_NOTE_OPEN) : -len(_NOTE_CLOSE)] if note else line
        texts.append((html.unescape(inner), note))
    return tuple(texts)


def as_html(texts: Iterable[tuple[str, bool]]) -> tuple[str, ...]:
    """:func:`as_text`'s lines as the editor shows them again, escaped."""
    return tuple(
        f"{_NOTE_OPEN}{printed(text)}{_NOTE_CLOSE}" if note else printed(text)
        for text, note in texts
    )


class RunOutput:
    """My run's printed lines under the editor, newest at the bottom, and the exceptions in them
    (the runner relays a traceback as output lines: the innermost line of my file is marked)."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self.traceback = TracebackReader()
        self.errors: list[Problem] = []
        self.printed: deque[str] = deque(maxlen=RUN_OUTPUT_LINES)  # HTML, escaped
        # The run's next line this pane expects, in its context's count (OutputLines.first):
        # None until known (a run found late, before its output so far came).
        self.next_line: int | None = None
        self.html = gui.add_html(self._html())

    def _html(self) -> str:
        # Newest at the bottom and kept in view: a column drawn in reverse scrolls there.
        body = output_html(self.printed, "Your run's output shows here.")
        return (
            '<div class="wart-run-output" style="max-height: 12em; overflow-y: auto; '
            f'display: flex; flex-direction: column-reverse">{body}</div>'
        )

    def clear(self, next_line: int | None = None) -> None:
        """A new run: its output only (from its line ``next_line``, if known)."""
        self.errors = []
        self.printed.clear()
        self.next_line = next_line
        self.html.content = self._html()

    def put_back(
        self, printed: tuple[str, ...], errors: tuple[Problem, ...], next_line: int | None = None
    ) -> None:
        self.errors = list(errors)
        self.printed.extend(printed)
        self.next_line = next_line
        self.html.content = self._html()

    def note(self, text: str) -> None:
        """A line of the lab's about the run (queued, running, ended), in italics."""
        self.add(f"{_NOTE_OPEN}{printed(text)}{_NOTE_CLOSE}")

    def add(self, line: str) -> None:
        self.printed.append(line)
        self.html.content = self._html()

    def numbered(self, first: int, texts: tuple[str, ...]) -> bool:
        """Of ``texts``, numbered from ``first`` in the run's count, those not shown yet
        (none twice; a gap is said); True if an exception was among them."""
        if self.next_line is not None:
            if first + len(texts) <= self.next_line:
                return False
            if first < self.next_line:
                texts, first = texts[self.next_line - first :], self.next_line
            elif first > self.next_line:
                self.note(f"{first - self.next_line} line(s) not received here")
        self.next_line = first + len(texts)
        return self.lines(texts)

    def lines(self, texts: list[str] | tuple[str, ...]) -> bool:
        """The controller's printed ``texts``; True if an exception was among them."""
        raised = False
        for text in texts:
            self.add(printed(text))
            found = self.traceback.feed(text)
            if found is not None:
                self.errors.append(found)
                raised = True
        return raised
