"""The doctor expects what the planner starts (no copy of the plan of its own)."""

from __future__ import annotations

from pathlib import Path

from common import keys
from common.keys import AliveKind
from common.zconfig import NetworkOptions
from services.commands.doctor import lab_file_plan, up_plan
from services.lab.labfile import load
from tests.conftest import REPO


def test_the_up_lab_is_expected_under_the_names_it_runs_with() -> None:
    plan = dict(up_plan(NetworkOptions(realm="lab")))
    # wart up's engine names its context "arena", its viewer is "web".
    assert plan["agent context arena"] == keys.alive("lab", AliveKind.CONTEXT, "arena")
    assert plan["viewer"] == keys.alive("lab", AliveKind.VIEWER, "web")
    assert plan["host local"] == keys.alive("lab", AliveKind.HOST, "local")
    assert "khepera emulator real1" not in plan  # off the network: its bridge stands for it


def test_a_lab_file_host_is_expected_as_wart_host_plans_it(tmp_path: Path) -> None:
    text = (REPO / "deploy" / "lab.example.toml").read_text()
    text = text.replace('# context = "arena"', 'context = "arena"')
    text = text.replace("http_port = 8080", 'http_port = 8080\nname = "front"')
    (tmp_path / "lab.toml").write_text(text)
    lab = load(tmp_path / "lab.toml")
    a, b = (dict(lab_file_plan(lab, lab.host(h))) for h in "AB")
    assert a["viewer"] == keys.alive("lab", AliveKind.VIEWER, "front")
    assert a["router"] == keys.alive("lab", AliveKind.ROUTER, "A")
    assert b["agent context arena"] == keys.alive("lab", AliveKind.CONTEXT, "arena")
    assert not (tmp_path / "state").exists() and not Path("/var/lib/wart/B").exists()
