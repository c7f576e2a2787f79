"""The terminal tools as a person uses them: `wart chat` in tmux, `wart users` on a database.

`wart chat` runs in a real tmux pane (keys sent, screen read back), against a
real registry and room on a real router; no mouse, no curses tricks.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.lab_client import LabClient
from common.messages import AuditQuery
from services.registry.accounts_db import RegistryDB
from services.registry.audit_db import TermStore
from tests.conftest import REPO, Procs, Router, wait_for, wart_env
from tests.kit.lab import PASSWORD, ProcessLab, make_lab, session_revoked

# One worker starts the module's router once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    lab.start_room("lobby")
    yield lab


class Pane:
    """A program in a detached tmux session of its own."""

    def __init__(self, command: list[str], env: dict[str, str]) -> None:
        self.name = f"wart-test-{uuid.uuid4().hex[:8]}"
        exports = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items())
        line = f"cd {shlex.quote(str(REPO))} && env {exports} {shlex.join(command)}"
        subprocess.run(
            ["tmux", "new-session", "-d", "-s", self.name, "-x", "160", "-y", "40", line],
            check=True,
        )

    def type(self, text: str) -> None:
        subprocess.run(["tmux", "send-keys", "-t", self.name, "-l", text], check=True)
        subprocess.run(["tmux", "send-keys", "-t", self.name, "Enter"], check=True)

    def screen(self) -> str:
        out = subprocess.run(
            ["tmux", "capture-pane", "-p", "-t", self.name], capture_output=True, text=True
        )
        return out.stdout

    def close(self) -> None:
        subprocess.run(["tmux", "kill-session", "-t", self.name], capture_output=True)


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_wart_chat_in_tmux_sees_history_members_and_live_lines(lab: ProcessLab) -> None:
    with lab.client("bob") as bob:
        heard: list[str] = []
        room = bob.join("lobby", on_event=lambda e: heard.append(e.line.text) if e.line else None)
        bob.say("lobby", "said before alice came")

        def lines() -> list[str]:
            return list(heard)

        env = {k: v for k, v in wart_env().items() if k in ("PYTHONPATH", "PATH", "HOME")}
        env["WART_PASSWORD"] = PASSWORD
        pane = Pane(
            [
                sys.executable,
                "-m",
                "services.cli",
                "chat",
                "lobby",
                "--user",
                "alice",
                *lab.net_args(),
            ],
            env,
        )
        try:
            # The room's header and then its history follow the join (the room's own
            # "alice joined" notice can come first, from another thread): wait for the
            # line said before alice came, which only the history can show her.
            wait_for(
                lambda: "room lobby" in pane.screen() and "said before alice came" in pane.screen(),
                30,
                "wart chat to join and show the room's history:\n" + pane.screen(),
            )
            pane.type("hello from the terminal")
            wait_for(lambda: "hello from the terminal" in lines(), 15, "bob to get the line")
            bob.say("lobby", "hi alice, live")
            wait_for(lambda: "<bob> hi alice, live" in pane.screen(), 15, "the live line")
            pane.type("/who")
            wait_for(lambda: "bob" in pane.screen().split("/who")[-1], 10, "the member list")
            pane.type("/quit")
            wait_for(lambda: "alice" not in room.members, 15, "alice to leave")
        finally:
            pane.close()


def run_users(db: Path, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "users", "--db", str(db), *args],
        input=stdin,
        capture_output=True,
        text=True,
        cwd=REPO,
        env=wart_env(),
        timeout=60,
    )


def test_wart_users_manages_accounts_and_explains_mistakes(lab: ProcessLab) -> None:
    db = lab.db_path
    # The new account's password comes from the piped line, never from WART_PASSWORD
    # (the variable people log in with).
    added = run_users(db, "add", "zoe", "--role", "student", stdin="zoe-first-pw\n")
    assert added.returncode == 0, added.stderr
    assert "zoe" in run_users(db, "list").stdout
    assert run_users(db, "grant", "zoe", "kick", "--scope", "ctx/lobby").returncode == 0
    grants = RegistryDB(db)
    try:
        assert any("kick" in str(g) and "ctx/lobby" in str(g) for g in grants.grants_of("zoe"))
    finally:
        grants.close()
    with lab.client() as before:
        before.login("zoe", "zoe-first-pw")
        changed = run_users(db, "passwd", "zoe", stdin="zoe-second-pw\n")
        assert changed.returncode == 0 and "(1 sessions ended)" in changed.stdout
        # The running registry enforces what the tool wrote in its file, within seconds.
        wait_for(lambda: session_revoked(before), 15, "zoe's old session ended")
    with lab.client() as client:
        client.login("zoe", "zoe-second-pw")  # the new password works on the running registry
    # Mistakes get a clear message and a non-zero exit, nothing half-done.
    dup = run_users(db, "add", "zoe", "--role", "student", stdin="x-password-1\n")
    assert dup.returncode != 0 and "zoe" in (dup.stderr + dup.stdout)
    bad = run_users(db, "add", "no/slash", "--role", "student", stdin="x-password-1\n")
    assert bad.returncode != 0 and "not a valid name" in (bad.stderr + bad.stdout)
    role = run_users(db, "add", "yan", "--role", "wizard", stdin="x-password-1\n")
    assert role.returncode != 0 and "wizard" in (role.stderr + role.stdout)
    assert run_users(db, "remove", "zoe").returncode == 0
    assert "zoe" not in run_users(db, "list").stdout
    with lab.client() as client, pytest.raises(Exception, match="wrong user name or password"):
        client.login("zoe", "zoe-second-pw")
    assert isinstance(client, LabClient)


def test_a_teacher_imports_a_class_and_a_student_logs_in_with_the_sheet(
    lab: ProcessLab, tmp_path: Path
) -> None:
    db = lab.db_path
    roster = tmp_path / "class.csv"
    roster.write_text("user,name,role,team\nkim,Kim Ode,student,red\nlou,Lou,teacher,\n")
    sheet = tmp_path / "slips.html"
    done = run_users(db, "import", str(roster), "--course", "rob26", "--sheet", str(sheet))
    assert done.returncode == 0, done.stderr
    assert "new accounts (2): kim, lou" in done.stdout
    assert sheet.stat().st_mode & 0o777 == 0o600  # the owner's eyes only
    found = dict(
        re.findall(
            r"user: <code>(\w+)</code><br>first password: <code>(\w+)</code>", sheet.read_text()
        )
    )
    assert sorted(found) == ["kim", "lou"]
    for password in found.values():  # never on the terminal
        assert password not in done.stdout + done.stderr
    with lab.client() as client:
        client.login("kim", found["kim"])  # the running registry takes the new account
    again = run_users(db, "import", str(roster), "--course", "rob26", "--sheet", str(sheet))
    assert again.returncode == 0 and "unchanged: 2" in again.stdout
    bad = tmp_path / "bad.csv"
    bad.write_text("user,role\nmia,student\nkim,pupil\n")
    refused = run_users(db, "import", str(bad), "--course", "rob26")
    assert refused.returncode != 0
    assert "line 3: role 'pupil' for kim" in refused.stderr and "nothing written" in refused.stderr
    assert "mia" not in run_users(db, "list").stdout  # nothing half-written
    members = run_users(db, "course", "rob26").stdout
    assert "teacher  lou" in members and "team red" in members
    store = RegistryDB(db)
    try:
        imports, _ = TermStore(store).entries(AuditQuery(action="import_roster"))
    finally:
        store.close()
    assert [a.target for a in imports] == ["course/rob26", "course/rob26"]
    assert not any(p in a.detail for a in imports for p in found.values())
