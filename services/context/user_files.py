"""Each user's controller files, kept by the agent context for the page's editor.

One folder per user under the context's data directory
(``<data-dir>/<ctx>.files/<user>/<name>.py``), the newest ``max_files`` kept
(saving one more drops the oldest), each at most ``max_bytes`` (the upload
limit: a file the lab could not run is not worth keeping), every write
atomic (common/files.py) so a crash leaves the old file or the new one.

Who may read what is decided by the caller passing the *authenticated* user
(the envelope's principal), never a name from the request: there is no way
to ask for another user's file. Names are checked again here (the wire type
already refuses anything but a plain ``.py`` name), so a path can never leave
the user's folder. Without a data directory (tests, a throwaway context) the
files live in memory, with the same limits.
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from common.files import write_atomic
from common.keys import is_ident
from common.messages import (
    FileContent,
    FileInfo,
    FileList,
    FileListRequest,
    Message,
    OkReply,
    ReadFile,
    SaveFile,
)
from common.messages.agent import FILE_NAME_PATTERN, MAX_UPLOAD_BYTES
from common.service import RequestError

log = logging.getLogger("wart.context.files")

MAX_FILES_PER_USER = 10
_NAME = re.compile(FILE_NAME_PATTERN)


class FileStoreError(ValueError):
    """A file that cannot be kept or found; the message is for the student."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code  # bad_request, too_large, not_found


@dataclass(frozen=True)
class StoredFile:
    name: str
    size: int
    saved_at: float


class UserFiles:
    def __init__(
        self,
        root: Path | None,
        *,
        max_files: int = MAX_FILES_PER_USER,
        max_bytes: int = MAX_UPLOAD_BYTES,
    ) -> None:
        self.root = root
        self.max_files = max_files
        self.max_bytes = max_bytes
        self._memory: dict[str, dict[str, tuple[bytes, float]]] = {}
        self._last_ns = 0  # saves get strictly increasing times: "newest" never ties
        self._lock = threading.Lock()  # one save at a time: "keep the newest N" is read-modify

    def _folder(self, user: str) -> Path:
        if not is_ident(user):
            raise FileStoreError("bad_request", f"{user!r} is not a user name")
        assert self.root is not None
        return self.root / user

    def _check_name(self, name: str) -> None:
        if not _NAME.match(name):
            raise FileStoreError(
                "bad_request",
                f"{name!r} is not a file name: letters, digits, '_', '-', '.', ending in .py",
            )

    def save(self, user: str, name: str, source: bytes) -> StoredFile:
        self._check_name(name)
        if len(source) > self.max_bytes:
            raise FileStoreError(
                "too_large",
                f"{name} is {len(source)} bytes; files are kept up to "
                f"{self.max_bytes // 1024} KiB (the upload limit)",
            )
        with self._lock:
            self._last_ns = max(time.time_ns(), self._last_ns + 1)
            now = self._last_ns / 1e9
            if self.root is None:
                files = self._memory.setdefault(user, {})
                files[name] = (source, now)
                for old, _ in self._listing_memory(user)[self.max_files :]:
                    del files[old]
            else:
                path = self._folder(user) / name
                # a student's code is theirs: never readable by other accounts here
                write_atomic(path, source, mode=0o600)
                # The file system's clock ticks coarsely (ms): order by our own, strictly rising.
                os.utime(path, ns=(self._last_ns, self._last_ns))
                for stale in self.listing(user)[self.max_files :]:
                    (self._folder(user) / stale.name).unlink(missing_ok=True)
        return StoredFile(name, len(source), now)

    def _listing_memory(self, user: str) -> list[tuple[str, float]]:
        files = self._memory.get(user, {})
        return sorted(((n, t) for n, (_, t) in files.items()), key=lambda f: (-f[1], f[0]))

    def listing(self, user: str) -> list[StoredFile]:
        """The user's files, newest first."""
        if self.root is None:
            files = self._memory.get(user, {})
            return [StoredFile(n, len(files[n][0]), t) for n, t in self._listing_memory(user)]
        folder = self._folder(user)
        found = []
        try:
            entries = list(os.scandir(folder))
        except FileNotFoundError:
            return []
        for entry in entries:
            if _NAME.match(entry.name) and entry.is_file(follow_symlinks=False):
                stat = entry.stat(follow_symlinks=False)
                found.append((stat.st_mtime_ns, entry.name, stat.st_size))
        found.sort(key=lambda f: (-f[0], f[1]))
        return [StoredFile(name, size, ns / 1e9) for ns, name, size in found]

    def read(self, user: str, name: str) -> tuple[bytes, float]:
        """(source, saved at) of the user's own file ``name``; not_found otherwise."""
        self._check_name(name)
        if self.root is None:
            kept = self._memory.get(user, {}).get(name)
            if kept is None:
                raise FileStoreError("not_found", f"you have no file named {name}")
            return kept
        path = self._folder(user) / name
        try:
            if path.is_symlink():  # never follow a link out of the folder
                raise FileNotFoundError(name)
            data = path.read_bytes()
            saved = path.stat().st_mtime
        except FileNotFoundError:
            raise FileStoreError("not_found", f"you have no file named {name}") from None
        return data[: self.max_bytes], saved

    def answer(self, user: str, request: SaveFile | FileListRequest | ReadFile) -> Message:
        """A request about ``user``'s own files (the authenticated sender, never a named one)."""
        try:
            if isinstance(request, SaveFile):
                saved = self.save(user, request.name, request.source)
                return OkReply(detail=f"saved {saved.name} ({saved.size} bytes)")
            if isinstance(request, ReadFile):
                source, saved_at = self.read(user, request.name)
                return FileContent(name=request.name, source=source, saved_at=saved_at)
            files = self.listing(user)[: self.max_files]
        except FileStoreError as exc:
            if exc.code == "not_found":
                raise RequestError("not_found", str(exc)) from None
            raise RequestError("bad_request", str(exc)) from None
        except OSError as exc:
            log.error("files of %s: %s", user, exc)
            raise RequestError("unavailable", "the lab could not reach your files now") from None
        return FileList(
            files=[FileInfo(name=f.name, size=f.size, saved_at=f.saved_at) for f in files],
            max_files=self.max_files,
            max_bytes=self.max_bytes,
        )
