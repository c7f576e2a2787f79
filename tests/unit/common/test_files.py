"""Atomic replacement and the append journal keep what was acknowledged."""

from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import pytest

from common import files
from common.files import Journal, write_atomic


def test_a_failed_write_leaves_the_old_file_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "map.json"
    write_atomic(path, b"old map")

    def power_cut(fd: int) -> None:
        raise OSError("disk gone")

    monkeypatch.setattr(files.os, "fsync", power_cut)
    with pytest.raises(OSError, match="disk gone"):
        write_atomic(path, b"new map, half written")
    assert path.read_bytes() == b"old map"


def test_a_journal_gives_back_every_whole_record_and_skips_a_torn_tail(tmp_path: Path) -> None:
    journal = Journal(tmp_path / "world.edits")
    for i in range(5):
        journal.append(f"edit {i}".encode())
    with open(journal.path, "ab") as out:  # a crash in the middle of the sixth append
        out.write(b"\x00\x00\x00\x40half")
    assert [r.decode() for r in journal.records()] == [f"edit {i}" for i in range(5)]
    journal.restart(b"base")
    assert list(journal.records()) == [b"base"]
    assert not list(Journal(tmp_path / "none").records())
    assert os.path.getsize(journal.path) == 8


def test_a_live_file_is_replaced_whole_without_syncing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    synced: list[int] = []
    monkeypatch.setattr(files.os, "fsync", synced.append)
    path = tmp_path / "truth.json"
    for poses in (b"old poses", b"new poses"):
        write_atomic(path, poses, durable=False)
    assert path.read_bytes() == b"new poses"
    assert synced == [], "a live file is never synced"
    assert [p.name for p in tmp_path.iterdir()] == ["truth.json"], "no temporary file left"


def test_a_private_file_is_never_readable_by_others_even_while_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Lease keys and students' code: 0600 from the temporary file's first byte, not
    from a chmod after the rename (another account could open it in between)."""
    path = tmp_path / "book.json"
    # A temporary file a crash left behind, readable by all: it is reused, not trusted.
    stale = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    stale.write_bytes(b"old")
    stale.chmod(0o644)
    modes: list[int] = []
    real_replace = os.replace

    def replace(src: Path, dst: Path) -> None:
        modes.append(stat.S_IMODE(os.stat(src).st_mode))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    old_umask = os.umask(0o022)
    try:
        write_atomic(path, b"secret", mode=0o600)
        write_atomic(tmp_path / "map.json", b"public")
    finally:
        os.umask(old_umask)
    assert modes == [0o600, 0o644]
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.read_bytes() == b"secret"
