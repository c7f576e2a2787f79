"""The suite leaves the checkout as it found it: a test writes under its tmp_path only.

A service run on a file of the checkout writes beside it (an engine's journal of live
edits, ``maps/.<world>.edits``): a test that starts one on a shipped map changes the
repository under the developer, and a file it leaves can end up committed. This plugin
(on the controller, not on xdist's workers) reads ``git status`` and the listed files'
contents before the session and after it, and fails the run naming every file a test
created, changed or removed. Outside a git checkout it does nothing.
"""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _status() -> dict[str, str] | None:
    """Each path git lists as changed or untracked (not ignored), with its content's hash."""
    try:
        listed = subprocess.run(
            ["git", "status", "--porcelain=v1", "--untracked-files=all", "-z"],
            cwd=REPO,
            capture_output=True,
            check=True,
            timeout=60,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    found: dict[str, str] = {}
    entries = iter(listed.decode(errors="replace").split("\0"))
    for entry in entries:
        if not entry:
            continue
        code, path = entry[:2], entry[3:]
        if code[0] in "RC":  # a rename or copy: its source path follows
            next(entries, None)
        try:
            digest = hashlib.sha256((REPO / path).read_bytes()).hexdigest()
        except OSError:  # a directory, or gone since git listed it
            digest = "-"
        found[path] = f"{code} {digest}"
    return found


class CheckoutGuard:
    def __init__(self) -> None:
        self.before = _status()
        self.changed: list[str] = []  # what the run created, changed or removed

    def pytest_sessionfinish(self, session: pytest.Session, exitstatus: int) -> None:
        if self.before is None:
            return
        after = _status()
        if after is None:
            return
        changed = sorted(
            path for path in self.before.keys() | after.keys()
            if self.before.get(path) != after.get(path)
        )  # fmt: skip
        if not changed:
            return
        self.changed = changed
        if session.exitstatus == pytest.ExitCode.OK:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED

    def pytest_terminal_summary(self, terminalreporter: pytest.TerminalReporter) -> None:
        if self.changed:
            terminalreporter.section("the checkout was changed by the run", red=True)
            terminalreporter.write_line(
                "A test wrote outside its tmp_path (or the checkout was edited meanwhile):"
            )
            for path in self.changed:
                terminalreporter.write_line(f"  {path}")
