"""`wart doctor` without a lab file: what any client sees, and what is wrong, in words."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from common.client.survey import survey
from common.service import close_session, open_session
from tests.conftest import REPO, Procs, Router, wart_env
from tests.kit.lab import make_lab


def doctor(router: Router) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "doctor", *router.net_args()],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=wart_env(),
        timeout=60,
    )


def test_survey_names_the_router_and_a_missing_registry(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    session = open_session(router.options(), wait=10)
    try:
        before = survey(session, router.realm)
    finally:
        close_session(session)
    assert [r.name for r in before.routers] == ["test-router"]
    assert any("no registry is alive" in p for p in before.problems)
    missing = doctor(router)
    assert missing.returncode == 1 and "no registry is alive" in missing.stdout

    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    healthy = doctor(router)
    assert healthy.returncode == 0, healthy.stdout
    assert "registry: registry" in healthy.stdout and "no problem found" in healthy.stdout
