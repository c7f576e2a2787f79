"""``wart doctor`` on a real ``wart up`` lab: every process of the plan is seen alive."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from common.zconfig import NetworkOptions
from services.commands.doctor import up_plan
from tests.conftest import REPO, wart_env
from tests.kit.lab import UpLab

pytestmark = pytest.mark.smoke


def test_the_doctor_finds_nothing_missing_in_a_healthy_up_lab(tmp_path: Path, realm: str) -> None:
    lab = UpLab(realm=realm, state_dir=tmp_path / "state").start()
    try:
        lab.wait_line("The lab is running", timeout=120)
        doctor = subprocess.run(
            [sys.executable, "-m", "services.cli", "doctor", "--realm", realm],
            cwd=REPO,
            env=wart_env({"WART_CONNECT": lab.endpoint}),
            capture_output=True,
            text=True,
            timeout=60,
        )
        out = doctor.stdout + doctor.stderr
        # What a user sees: every service of the plan alive, none reported missing.
        assert doctor.returncode == 0, out
        assert "no problem found" in out and "✗" not in out, out
        plan = up_plan(NetworkOptions(realm=realm))
        for what, _key in plan:
            assert f"✓ {what} is alive" in out, out
        # The names the old hand-written copy got wrong: the engine's context, the viewer's id.
        assert {"agent context arena", "viewer", "bridge real1"} <= {w for w, _ in plan}
    finally:
        lab.stop()
