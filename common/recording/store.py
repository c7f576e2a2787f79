"""An agent context's recordings on disk: one directory per user, the oldest removed past a limit.

Layout: ``<root>/<user>/<request id>.mcap`` and, beside it,
``<request id>.summary.json`` (the :class:`~common.recording.summary.Summary`).
A run still being written is ``<request id>.mcap.part`` (not listed). Names
are validated identifiers, so no request can reach outside the root.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import msgspec

from common import keys
from common.files import write_atomic
from common.messages import RecordingInfo
from common.recording.summary import Summary
from common.recording.writer import PART

log = logging.getLogger("wart.recording")

SUFFIX = ".mcap"
SUMMARY = ".summary.json"


class RecordingStore:
    def __init__(self, root: Path, keep: int) -> None:
        if keep < 1:
            raise ValueError("keep at least one recording per user")
        self.root = root
        self.keep = keep
        root.mkdir(parents=True, exist_ok=True)
        os.chmod(root, 0o700)

    def path_for(self, user: str, name: str) -> Path:
        keys.check_ident("user", user)
        keys.check_ident("recording", name)
        return self.root / user / f"{name}{SUFFIX}"

    def users(self) -> list[str]:
        return sorted(p.name for p in self.root.iterdir() if p.is_dir() and keys.is_ident(p.name))

    def files(self, user: str) -> list[Path]:
        """A user's finished recordings, oldest first (by modification time, then name)."""
        folder = self.root / keys.check_ident("user", user)
        if not folder.is_dir():
            return []
        found = [p for p in folder.glob(f"*{SUFFIX}") if keys.is_ident(p.stem)]
        return sorted(found, key=lambda p: (p.stat().st_mtime, p.name))

    def find(self, name: str) -> tuple[str, Path] | None:
        """(owner, path) of the recording called ``name``, if any."""
        keys.check_ident("recording", name)
        for user in self.users():
            path = self.root / user / f"{name}{SUFFIX}"
            if path.is_file():
                return user, path
        return None

    def summary_path(self, path: Path) -> Path:
        return path.with_name(path.stem + SUMMARY)

    def save_summary(self, path: Path, summary: Summary) -> None:
        target = self.summary_path(path)
        write_atomic(target, msgspec.json.encode(summary), mode=0o600)

    def summary(self, path: Path) -> Summary | None:
        try:
            return msgspec.json.decode(self.summary_path(path).read_bytes(), type=Summary)
        except (OSError, msgspec.ValidationError, msgspec.DecodeError):
            return None

    def info(self, user: str, path: Path) -> RecordingInfo:
        st = path.stat()
        summary = self.summary(path)
        return RecordingInfo(
            name=path.stem,
            user=user,
            agent=summary.agent if summary else path.stem.split("-", 1)[0],
            start=summary.start if summary else st.st_mtime,
            size=st.st_size,
            status=summary.status if summary else "",
            reason=(summary.reason if summary else "")[:256],
            distance_mm=summary.distance_mm if summary else None,
            duration_s=summary.duration_s if summary else None,
        )

    def listing(self, users: list[str]) -> list[RecordingInfo]:
        return [self.info(user, p) for user in users for p in self.files(user)]

    def prune(self, user: str) -> list[Path]:
        """Remove ``user``'s oldest recordings beyond the limit; the paths removed."""
        removed = []
        files = self.files(user)
        for path in files[: max(0, len(files) - self.keep)]:
            for p in (path, self.summary_path(path)):
                try:
                    p.unlink(missing_ok=True)
                except OSError as exc:
                    log.warning("could not remove %s: %s", p, exc)
            removed.append(path)
        if removed:
            log.info(
                "removed %d old recording(s) of %s (keeping %d)", len(removed), user, self.keep
            )
        return removed

    def salvage_parts(self) -> list[Path]:
        """Runs cut short by a crash of the context: renamed to finished names, kept readable
        (the reader salvages them and says they were cut short)."""
        done = []
        for part in self.root.glob(f"*/*{SUFFIX}{PART}"):
            target = part.with_name(part.name[: -len(PART)])
            try:
                os.replace(part, target)
                done.append(target)
            except OSError as exc:
                log.warning("could not keep %s: %s", part, exc)
        return done
