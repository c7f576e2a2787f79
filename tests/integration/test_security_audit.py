"""An audit trail that cannot be buried, against a real registry on a real SQLite file:
a thousand refusals are a couple of counted lines, a service's report replayed (also
after a registry restart) is kept once, and forged reports are in `wart audit`."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common import keys
from common.auth import create_identity_key
from common.client.lab_client import LabClient
from common.lab_errors import NotAllowed
from common.messages import AuditEntry, AuditReport
from common.service import close_session
from services.registry.accounts_db import RegistryDB
from tests.conftest import REPO, Procs, Router, wait_for, wart_env
from tests.kit.lab import PASSWORD, ProcessLab, audit_trail, registry_lab


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    return registry_lab(router, procs, tmp_path)


def _counted(entries: list[AuditEntry]) -> int:
    """Refusals the lines stand for: one each, or the N of "N more refused ..."."""
    total = 0
    for entry in entries:
        more = re.match(r"(\d+) more refused in the minute from", entry.detail)
        total += int(more.group(1)) if more else 1
    return total


def test_a_thousand_refusals_are_a_few_counted_lines(lab: ProcessLab) -> None:
    t0 = time.monotonic()
    with lab.client("bob") as bob:
        for _ in range(1000):
            with pytest.raises(NotAllowed):
                bob.list_users()
    print(f"1000 refused requests in {time.monotonic() - t0:.1f} s")
    with lab.client("admin") as admin:
        lines = audit_trail(admin, actor="bob", action="list_users")
        assert len(lines) <= 4  # a first line and a count, per minute the flood spanned
        assert _counted(lines) == 1000
        assert all(line.outcome == "refused" for line in lines)


def test_a_replayed_report_is_kept_once_and_forged_ones_are_shown(lab: ProcessLab) -> None:
    key_file = create_identity_key(lab.state / "engine.key")
    db = RegistryDB(lab.db_path)
    db.add_user("engine-test", ["service"], public_key=bytes(key_file.verify_key))
    db.close()
    where = keys.registry_report(lab.realm)
    session = lab.zsession()
    try:
        engine = LabClient(session, lab.realm, lab.identity.verify_key, presence=False)
        engine.login_with_key("engine-test", key_file)
        assert engine.session is not None
        report = AuditReport(
            at=time.time(), actor="ida", action="estop", target="world/arena", outcome="ok",
            detail="the captured one",
        )  # fmt: skip
        captured = engine.session.seal(where, report)
        session.put(where, captured)
        session.put(where, captured)  # a replay, to the same registry
        with lab.client("admin") as admin:
            wait_for(lambda: audit_trail(admin, action="estop"), 10, "the report kept")
        assert lab.registry is not None
        lab.registry.kill9()  # the replay window in its memory goes with it
        lab.start_registry()
        session.put(where, captured)  # the same bytes again, still fresh
        with lab.client("bob") as bob:  # a student's session puts a report of its own
            assert bob.session is not None
            lie = AuditReport(
                at=time.time(), actor="admin", action="ban", target="carol", outcome="ok"
            )
            session.put(where, bob.session.seal(where, lie))
            # Bob stays logged in until his lie is judged: his logout (another session, so
            # no order between the two) could revoke the session first, and the lie would be
            # refused as a revoked session's, unnamed.
            with lab.client("admin") as admin:
                wait_for(
                    lambda: (
                        [e for e in audit_trail(admin, action="forged_report") if e.actor == "bob"]
                        or None
                    ),
                    10,
                    "bob's report judged",
                )
            bob_session = bob.session
        # Logged out (his session revoked), bob reports again with its key: refused, and
        # still his name on the line, as his key signed it.
        lie = AuditReport(at=time.time(), actor="admin", action="ban", target="dan", outcome="ok")
        session.put(where, bob_session.seal(where, lie))
        session.put(where, b"not a report at all")
        with lab.client("admin") as admin:
            forged = wait_for(
                lambda: len(audit_trail(admin, action="forged_report")) >= 3 or None,
                10,
                "the forged reports recorded",
            )
            assert forged
            assert len(audit_trail(admin, action="estop")) == 1  # kept once, past the restart
            trail = audit_trail(admin, action="forged_report")
            lines = {(e.actor, e.target) for e in trail}
            assert ("bob", "carol") in lines and ("unknown", "audit") in lines
            revoked = [e for e in trail if e.actor == "bob" and e.target == "audit"]
            assert len(revoked) == 1 and "revoked" in revoked[0].detail
            assert "replayed" in revoked[0].detail  # a capture replayed would read the same
            assert not audit_trail(admin, action="ban")  # the lie is not a ban line
    finally:
        close_session(session)
    admin_args = ["--user", "admin", *lab.net_args()]
    shown = subprocess.run(
        [sys.executable, "-m", "services.cli", "audit", "--action", "forged_report", *admin_args],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=wart_env({"WART_PASSWORD": PASSWORD}),
        timeout=60,
    )
    assert shown.returncode == 0, shown.stderr
    assert "forged_report" in shown.stdout and "is not a service" in shown.stdout
