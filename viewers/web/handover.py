"""What the viewer's pages have open, for the next viewer to open again.

A viewer that stops (an upgrade, a restart by its supervisor, a pod moved) hands
its lab sessions over instead of logging them out (LabConnection.hand_over): their
runs go on, and each page, reconnecting to the next viewer at the same address,
logs in again by its saved login. What the page had open lived in the old
process's memory; this book keeps the part the next viewer can use, in the
viewer's data directory: per saved login, the contexts that were joined, the
one whose world was in view, and each arena's editor (its file name, its text,
saved or not, and the robot chosen). The page comes back to them, not to the lobby.

A viewer that crashes writes nothing at its end, so the book is also a journal:
:class:`PageJournal` notes every open and parked page every ``JOURNAL_PERIOD_S``
and writes the file when what they have open changed. After a crash the page
comes back as the last note left it (its editor as it was at most a period before).

A saved login is named here by the SHA-256 of its resume token, never the token:
the file lets no one log in. An entry is good once and for ``MAX_AGE_S``; a file
that cannot be read is set aside with a warning and an empty book is started.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import msgspec

from common.files import write_atomic
from common.keys import is_ident
from common.messages.agent import MAX_OUTPUT_LINE
from viewers.web.run_output import RUN_OUTPUT_LINES, as_text
from viewers.web.workbench import BenchMemory

log = logging.getLogger("wart.viewer.handover")

HANDOVER_FILE = "handed-over.json"
MAX_AGE_S = 3600.0  # a page back later than this starts in the lobby
MAX_ENTRIES = 10_000
MAX_CONTEXTS = 64  # per page: more than anyone opens
MAX_EDITOR_CHARS = 256 * 1024  # four times what a controller may be (upload_gate.py)
MAX_NAME_CHARS = 200
MAX_PRINTED_CHARS = 2 * MAX_OUTPUT_LINE  # a printed line, or the lab's note about the run
CLOCK_SKEW_S = 60.0  # an entry stamped later than this ahead of now was not written here
JOURNAL_PERIOD_S = 5.0  # what a crash can lose of a page's editor
SIBLING_WINDOW_S = 120.0  # after a start, the tabs of one browser coming back (take())
# An unchanged journal is written again this often: its entries' age is the time since
# the last note, and a page still open at a crash is then not taken for an old one.
JOURNAL_REFRESH_S = 600.0


class EditorText(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """An arena's editor as the page left it: unsaved text is a student's work, and the
    run's output so far under it (plain text, each line with whether it is the lab's note;
    escaped again when shown: run_output.as_text / as_html)."""

    ctx: str
    file_name: str
    code: str
    target: str  # the robot chosen to run on
    printed: tuple[tuple[str, bool], ...] = ()
    printed_on: str | None = None  # the robot whose run printed it (in ``ctx``)


class HandedOver(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One page's lab, as the viewer that stopped left it."""

    user: str
    contexts: tuple[str, ...]  # joined, in the order they were opened
    watching: str | None  # the context whose world was in view
    at: float  # wall-clock time of the hand-over
    editors: tuple[EditorText, ...] = ()

    def same_page(self, other: HandedOver) -> bool:
        """The same user, contexts, view and editors (whenever each was noted)."""
        return (self.user, self.contexts, self.watching, self.editors) == (
            other.user,
            other.contexts,
            other.watching,
            other.editors,
        )

    def editor(self, ctx: str) -> EditorText | None:
        return next((e for e in self.editors if e.ctx == ctx), None)

    @classmethod
    def of(
        cls, user: str, opened: Sequence[tuple[str, BenchMemory | None]], watching: str | None
    ) -> HandedOver:
        """A page's lab as it is now: each joined context in order, with its editor if an
        arena's; ``watching``, the one in view (kept only if among them)."""
        contexts = tuple(ctx for ctx, _ in opened)
        editors = tuple(
            EditorText(
                ctx,
                bench.file_name,
                bench.code,
                bench.target,
                as_text(bench.printed),
                _printed_on(ctx, bench),
            )
            for ctx, bench in opened
            if bench is not None
        )
        shown = watching if watching in contexts else None
        return cls(user, contexts, shown, time.time(), editors)


class HandOverBook:
    def __init__(self, path: Path | None, max_age_s: float = MAX_AGE_S) -> None:
        self.path = path
        self.max_age_s = max_age_s
        self._lock = threading.Lock()
        # One write at a time, each of the state it read: an older state written last
        # would bring back an entry already taken.
        self._writing = threading.Lock()
        self._entries: dict[str, HandedOver] = {}  # the last viewer's, each taken once
        self._open: dict[str, HandedOver] = {}  # this viewer's pages, as last noted
        self._written_at = 0.0
        self._failing = False  # the last write failed (said once)
        self._issued: set[str] = set()  # saved logins this viewer gave pages
        self._started = time.monotonic()
        self._entries, dropped = self._read()
        if dropped:  # out of date, or not sound: no student's text stays for nothing
            self.save()
        if self._entries:
            newest = max(entry.at for entry in self._entries.values())
            log.info(
                "the tabs of %d page(s) kept by the last viewer here (noted up to %.0f s "
                "ago): each reopens as its page comes back with its saved login",
                len(self._entries),
                max(0.0, time.time() - newest),
            )

    @staticmethod
    def name(token: bytes) -> str:
        return hashlib.sha256(token).hexdigest()

    def _read(self) -> tuple[dict[str, HandedOver], int]:
        """The entries still good, and how many were dropped."""
        if self.path is None or not self.path.exists():
            return {}, 0
        try:
            raw = msgspec.json.decode(self.path.read_bytes(), type=dict[str, HandedOver])
        except (OSError, msgspec.ValidationError, msgspec.DecodeError) as exc:
            aside = self.path.with_name(self.path.name + ".unreadable")
            log.warning(
                "the pages handed over by the last viewer (%s) could not be read (%s): "
                "set aside as %s; those pages come back to their lab's lobby",
                self.path,
                exc,
                aside.name,
            )
            with contextlib.suppress(OSError):  # a read-only directory: read it again
                self.path.replace(aside)
            return {}, 0
        now = time.time()
        good = {
            name: entry
            for name, entry in raw.items()
            if self._sound(name, entry) and -CLOCK_SKEW_S <= now - entry.at <= self.max_age_s
        }
        if len(good) > MAX_ENTRIES:  # not one viewer's: the newest are the ones coming back
            newest = sorted(good.items(), key=lambda item: item[1].at)[-MAX_ENTRIES:]
            good = dict(newest)
        return good, len(raw) - len(good)

    @staticmethod
    def _sound(name: str, entry: HandedOver) -> bool:
        # Names are read back into the page's joins: only what a context can be called.
        return (
            len(name) == 64
            and math.isfinite(entry.at)  # JSON has no inf: it would make the file unreadable
            and all(c in "0123456789abcdef" for c in name)
            and is_ident(entry.user)
            and len(entry.contexts) <= MAX_CONTEXTS
            and all(is_ident(ctx) for ctx in entry.contexts)
            and (entry.watching is None or entry.watching in entry.contexts)
            and all(_sound_editor(e, entry.contexts) for e in entry.editors)
        )

    def note_open(self, pages: Sequence[tuple[bytes, HandedOver]]) -> bool:
        """What this viewer's pages have open now, by saved login: the file is written
        if that changed (or was last written ``JOURNAL_REFRESH_S`` ago). True if written."""
        noted: dict[str, HandedOver] = {}
        for token, page in pages[:MAX_ENTRIES]:
            if self._sound(self.name(token), page):
                noted[self.name(token)] = page
            else:
                log.warning(
                    "a page of %r was not noted for the next viewer: unexpected names", page.user
                )
        with self._lock:
            same = noted.keys() == self._open.keys() and all(
                page.same_page(self._open[name]) for name, page in noted.items()
            )
            recent = time.monotonic() - self._written_at < JOURNAL_REFRESH_S
            if same and recent and not self._failing:
                return False
            self._open = noted
        self.save()
        return True

    def save(self) -> None:
        if self.path is None:
            return
        with self._writing:
            self._write(self.path)

    def _write(self, path: Path) -> None:
        with self._lock:
            data = msgspec.json.encode({**self._entries, **self._open})
        try:
            write_atomic(path, data, mode=0o600)  # students' code: theirs alone
            self._written_at = time.monotonic()
        except OSError as exc:
            if not self._failing:  # once, not at every note while the disk stays full
                log.warning(
                    "could not keep the pages' tabs for the next viewer in %s: %s; after a "
                    "restart the pages come back to their lab's lobby (their runs go on)",
                    path,
                    exc,
                )
            self._failing = True
            return
        if self._failing:
            log.info("the pages' tabs are kept for the next viewer in %s again", path)
            self._failing = False

    def issued(self, token: bytes) -> None:
        """A saved login this viewer gave a page (at a login or a resume); only those of its
        first ``SIBLING_WINDOW_S`` count (take()), so only those are kept."""
        if time.monotonic() - self._started >= SIBLING_WINDOW_S:
            return
        with self._lock:
            self._issued.add(self.name(token))

    def take(self, token: bytes, user: str) -> HandedOver | None:
        """What the page of this saved login had open, once; None if nothing (or too old).

        Two tabs of one browser share its cookie, so both come back with the one saved
        login it holds: the first takes that one's page, and the second brings the login
        this viewer just gave the first (read from the cookie, or after a reload when it
        was refused as used: client.py), under which nothing was left. Such a login,
        within ``SIBLING_WINDOW_S`` of this viewer's start, takes another page its user
        left here, the newest: each tab gets one. Any other takes only its own.
        """
        with self._lock:
            name = self.name(token)
            entry = self._entries.pop(name, None)
            sibling = time.monotonic() - self._started < SIBLING_WINDOW_S
            if entry is None and sibling and name in self._issued:
                mine = [name for name, e in self._entries.items() if e.user == user]
                if not mine:
                    return None
                newest = max(mine, key=lambda name: self._entries[name].at)
                entry = self._entries.pop(newest)
            if entry is None:
                return None
        self.save()
        if entry.user != user or not -CLOCK_SKEW_S <= time.time() - entry.at <= self.max_age_s:
            return None
        return entry


def _printed_on(ctx: str, bench: BenchMemory) -> str | None:
    """The robot whose run printed the editor's output: followed there, or found again."""
    if bench.running_on is not None:
        return bench.running_on[1] if bench.running_on[0] == ctx else None
    return bench.output_of


def _sound_editor(editor: EditorText, contexts: tuple[str, ...]) -> bool:
    # Shown in the editor, never run from here: bounded text, names without controls.
    names = (editor.file_name, editor.target)
    return (
        editor.ctx in contexts
        and len(editor.code) <= MAX_EDITOR_CHARS
        and all(len(n) <= MAX_NAME_CHARS and n.isprintable() for n in names)
        and len(editor.printed) <= RUN_OUTPUT_LINES
        and all(len(text) <= MAX_PRINTED_CHARS for text, _ in editor.printed)
        and (editor.printed_on is None or is_ident(editor.printed_on))
    )


class PageJournal:
    """Notes what the viewer's pages have open in the book every ``period_s`` (a thread),
    so that a viewer that crashes leaves it too; ``pages`` says it, by saved login."""

    def __init__(
        self,
        book: HandOverBook,
        pages: Callable[[], Sequence[tuple[bytes, HandedOver]]],
        period_s: float = JOURNAL_PERIOD_S,
    ) -> None:
        self.book = book
        self._pages = pages
        self._period_s = period_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self.book.path is None:
            return  # no data directory: nothing to keep, and no next viewer reads it
        self._thread = threading.Thread(target=self._run, name="page-journal", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period_s):
            try:
                self.book.note_open(self._pages())
            except Exception:  # the next note tries again; the pages are not touched
                log.exception("could not note the open pages for the next viewer")

    def stop(self) -> None:
        """No more notes (the viewer's stop writes the last, from its hand-over)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
