"""One module builds every process's command line: ``wart up``'s lab and a lab file's hosts."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from common.zconfig import NetworkOptions
from services.commands.up import (
    LabSettings,
    lab_plan,
    local_wiring,
    service_accounts,
    settings_from_args,
)
from services.lab.labfile import LabFileError, service_entry
from services.lab.wiring import service_specs


def settings(tmp_path: Path) -> LabSettings:
    args = argparse.Namespace(state_dir=tmp_path, port=17447, http_port=18080)
    return settings_from_args(args, NetworkOptions(realm="lab"))


def flag(argv: list[str] | tuple[str, ...], name: str) -> str:
    return argv[list(argv).index(name) + 1]


def test_wart_up_runs_the_one_host_lab_in_dependency_order(tmp_path: Path) -> None:
    plan = lab_plan(settings(tmp_path))
    assert [s.name for s in plan] == [
        "registry",
        "chat lobby",
        "engine arena1",
        "agent context arena",
        "khepera emulator real1",
        "bridge real1",
        "camera real1-cam",
        "runner runner",
        "grader grader",
        "agent context robots",
        "viewer",
    ]
    by_name = {s.name: list(s.argv) for s in plan}
    # The simulated arena's context keeps its name, its owner and its runner.
    arena = by_name["agent context arena"]
    assert (flag(arena, "--world"), flag(arena, "--owner"), flag(arena, "--runner")) == (
        "arena1",
        "admin",
        "runner",
    )
    assert flag(arena, "--title") == "Arena (simulated)"
    # The bridge drives the emulated Khepera's pty, its odometry at the map's pose.
    emulator, bridge = by_name["khepera emulator real1"], by_name["bridge real1"]
    assert flag(bridge, "--port") == f"{flag(emulator, '--link')}=k1@500,500,0"
    # Its wheels slip (odometry drifts as a real robot's); its synthetic camera renders
    # the true poses it writes, and calibrates itself from the reference markers.
    camera = by_name["camera real1-cam"]
    assert flag(emulator, "--slip") == "0.03"
    assert flag(camera, "--source") == f"synthetic:{flag(emulator, '--truth')}"
    assert "--auto-calibrate" in camera
    # Every child reaches the lab's router, never scouting for another.
    for spec in plan:
        if spec.name != "khepera emulator real1":
            assert "--no-multicast-scouting" in spec.argv, spec.name
            assert flag(spec.argv, "--connect") == "tcp/127.0.0.1:17447", spec.name
    assert flag(by_name["viewer"], "--http-port") == "18080"


def test_every_account_a_process_logs_in_with_is_provisioned(tmp_path: Path) -> None:
    lab = settings(tmp_path)
    provisioned = set(service_accounts(lab))
    used = {flag(s.argv, "--user") for s in lab_plan(lab) if "--user" in s.argv}
    assert used <= provisioned, used - provisioned
    # Arenas and rooms started on request share one account per kind.
    assert {"agent-local", "room-local", "engine-arena1", "bridge-real1"} <= provisioned


def test_a_lab_file_service_says_who_owns_it_and_whether_it_logs_in() -> None:
    engine = service_entry(
        "s", {"kind": "engine", "world": "w1", "map": "m", "context": "c1", "login": True}
    )
    assert engine.params["context"] == "c1" and engine.params["login"] is True
    with pytest.raises(LabFileError, match=r"s.login: expected true or false"):
        service_entry("s", {"kind": "bridge", "world": "w", "emulate": "m", "login": "yes"})
    with pytest.raises(LabFileError, match=r"s.owner"):
        service_entry("s", {"kind": "chat", "name": "r", "owner": "no such/user"})


def test_a_grader_grades_as_many_at_once_as_its_lab_file_says(tmp_path: Path) -> None:
    # A scaled runner's pods get work only if the grader hands out that much at once.
    grader = service_entry("g", {"kind": "grader", "workers": 6})
    wiring = local_wiring(settings(tmp_path))
    (spec,) = service_specs(wiring, grader)
    assert spec.argv[spec.argv.index("--workers") + 1] == "6"
    (default,) = service_specs(wiring, service_entry("g", {"kind": "grader"}))
    assert "--workers" not in default.argv
    for bad in (0, 65, "six", True):
        with pytest.raises(LabFileError, match=r"g.workers"):
            service_entry("g", {"kind": "grader", "workers": bad})
