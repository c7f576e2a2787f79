"""What ``wart host`` would run on each host of the example lab (no process started)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from services.lab.labfile import LabFileError, load, parse
from services.lab.pki import host_roles, issue_lab, service_accounts
from services.lab.plan import HostContext, host_plan, read_registry_key, write_configs
from services.lab.zsecurity import ROLE_GRANTS
from tests.conftest import REPO

EXAMPLE = REPO / "deploy" / "lab.example.toml"


@pytest.fixture(scope="module")
def lab_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("hostplan")
    shutil.copy(EXAMPLE, tmp / "lab.toml")
    issue_lab(load(tmp / "lab.toml"), say=lambda _text: None)
    return tmp


def plan(lab_dir: Path, host: str) -> dict[str, list[str]]:
    lab = load(lab_dir / "lab.toml")
    ctx = HostContext(lab, lab.host(host), lab_dir / "state" / host, read_registry_key(lab))
    write_configs(ctx)
    return {spec.name: spec.argv for spec in host_plan(ctx)}


def test_each_host_runs_its_services_and_arenas_with_their_contexts(lab_dir: Path) -> None:
    a, b, c = (plan(lab_dir, h) for h in "ABC")
    assert list(a) == ["registry", "chat lobby", "viewer"]
    assert a["viewer"][:7] == ["viewer", "--id", "A", "--http-port", "8080", "--host", "10.0.0.1"]
    # The viewer's gateway account: it vouches for browsers' addresses at login.
    assert a["viewer"][a["viewer"].index("--user") + 1] == "viewer-viewer"
    # B's engine is an arena: its agent context ([arena].agent) comes
    # with it and names B's runner, started after it (a job only asks it later).
    assert list(b) == ["engine arena1", "agent context arena1", "runner runner"]
    agent = b["agent context arena1"]
    assert agent[agent.index("--runner") + 1] == "runner"
    assert agent[agent.index("--user") + 1] == "agent-B"
    # C's bridge on real hardware, and the agent context for it (B's runner).
    assert list(c) == ["bridge real1", "agent context robots"]
    robots = c["agent context robots"]
    assert robots[robots.index("--runner") + 1] == "runner"
    assert "--config" in robots and robots[robots.index("--config") + 1].endswith("agent.json5")


def test_an_emulated_khepera_precedes_its_bridge_at_the_map_pose(lab_dir: Path) -> None:
    text = (lab_dir / "lab.toml").read_text().replace('# emulate = "empty"', 'emulate = "empty"')
    (lab_dir / "emulated.toml").write_text(text)
    lab = load(lab_dir / "emulated.toml")
    ctx = HostContext(lab, lab.host("C"), lab_dir / "state-e", read_registry_key(lab))
    specs = host_plan(ctx)
    assert [s.name for s in specs][:2] == ["khepera emulator real1", "bridge real1"]
    assert specs[0].alive_key is None
    ports = [specs[1].argv[i + 1] for i, a in enumerate(specs[1].argv) if a == "--port"]
    assert ports[1].endswith("real1-khepera=k2@500,500,0"), ports


def test_certificates_and_accounts_cover_every_service(lab_dir: Path) -> None:
    lab = load(lab_dir / "lab.toml")
    assert host_roles(lab, "A") == ["router", "host", "registry", "chat", "viewer"]
    assert set(host_roles(lab, "B")) >= {"engine", "agent", "runner"}
    assert set(host_roles(lab, "C")) >= {"bridge", "agent", "engine"}
    assert service_accounts(lab, "B") == ["runner-runner", "agent-B"]
    assert service_accounts(lab, "C") == ["ctx-robots", "agent-C"]
    accounts = json.loads((lab.security.pki / "accounts.json").read_text())
    assert {"chat-lobby", "runner-runner", "ctx-robots", "agent-B", "agent-C"} <= set(accounts)
    pki = lab.security.pki
    for host, role in (("A", "viewer"), ("B", "runner"), ("B", "agent"), ("C", "bridge")):
        assert (pki / host / f"{role}.pem").is_file(), (host, role)


def test_the_runner_holds_no_right_to_frames_samples_or_leases() -> None:
    published = {k for g in ROLE_GRANTS["runner"] if g.verb == "pub" for k in g.keys}
    assert published == {"world/*/agent/*/cmd", "world/*/cmds", "ctx/*/output"}
    assert not any(word in k for k in published for word in ("frame", "sens", "sample", "lease"))
    assert not any(
        g.verb == "token" and "context" in k for g in ROLE_GRANTS["viewer"] for k in g.keys
    )


def test_an_agent_context_names_a_known_runner(tmp_path: Path) -> None:
    data = {
        "realm": "lab",
        "security": {"pki": "pki"},
        "hosts": [
            {"name": "A", "address": "10.0.0.1", "services": [{"kind": "registry"}]},
            {
                "name": "B",
                "address": "10.0.0.2",
                "services": [{"kind": "agent", "name": "r", "world": "w", "runner": "nope"}],
            },
        ],
    }
    with pytest.raises(LabFileError, match=r"hosts\[1\].services\[0\].runner"):
        parse(data, tmp_path / "lab.toml")
    data["hosts"][1]["services"] = [{"kind": "bridge", "world": "w"}]
    with pytest.raises(LabFileError, match=r"'ports'.*or 'emulate'"):
        parse(data, tmp_path / "lab.toml")


def test_a_swarm_arena_runs_its_engine_on_the_drive_the_lab_file_names(lab_dir: Path) -> None:
    text = (lab_dir / "lab.toml").read_text().replace('map = "foraging"', 'map = "swarm"')
    text = text.replace('# drive = "discs"', 'drive = "discs"')
    (lab_dir / "swarm.toml").write_text(text)
    lab = load(lab_dir / "swarm.toml")
    ctx = HostContext(lab, lab.host("B"), lab_dir / "state-s", read_registry_key(lab))
    engine = next(s.argv for s in host_plan(ctx) if s.name == "engine arena1")
    assert engine[engine.index("--drive") + 1] == "discs"
    assert engine[engine.index("--map") + 1].endswith("swarm.json")
    # A drive the engine does not have is refused when the file is read, naming the field.
    (lab_dir / "typo.toml").write_text(text.replace('drive = "discs"', 'drive = "disks"'))
    with pytest.raises(LabFileError, match=r"services\[0\]\.drive: 'disks' is not a drive"):
        load(lab_dir / "typo.toml")


def test_arenas_are_data_their_processes_built_like_any_other(lab_dir: Path) -> None:
    """[arena] says what an arena is; the command lines are wiring's, as for every process."""
    text = (lab_dir / "lab.toml").read_text()
    (lab_dir / "slots.toml").write_text(text.replace("# slot_seconds = 60", "slot_seconds = 3"))
    lab = load(lab_dir / "slots.toml")
    ctx = HostContext(lab, lab.host("B"), lab_dir / "state-slots", read_registry_key(lab))
    agent = next(s.argv for s in host_plan(ctx) if s.name == "agent context arena1")
    assert agent[agent.index("--slot-seconds") + 1] == "3"
    assert agent[:2] == ["context", "agent"] and "--title" in agent
    (lab_dir / "bare.toml").write_text(text.replace("agent = true", "agent = false"))
    lab = load(lab_dir / "bare.toml")
    ctx = HostContext(lab, lab.host("B"), lab_dir / "state-bare", read_registry_key(lab))
    assert [s.name for s in host_plan(ctx)] == ["engine arena1", "runner runner"]


def test_planning_writes_nothing_a_generated_map_is_written_at_start(lab_dir: Path) -> None:
    """The doctor plans hosts it does not run on: a plan is data until the supervisor spawns."""
    text = (lab_dir / "lab.toml").read_text().replace("seed = 1", "seed = 1\nrobots = 5")
    text = text.replace('# emulate = "empty"', 'emulate = "empty"')
    (lab_dir / "robots.toml").write_text(text)
    lab = load(lab_dir / "robots.toml")
    state = lab_dir / "state-robots"
    specs = []
    for host in ("B", "C"):
        ctx = HostContext(lab, lab.host(host), state / host, read_registry_key(lab))
        specs += host_plan(ctx)
    assert not state.exists()
    engine = next(s for s in specs if s.name == "engine arena1")
    map_path = Path(engine.argv[engine.argv.index("--map") + 1])
    assert engine.prepare is not None
    engine.prepare()
    assert map_path.is_file() and "agent_groups" in map_path.read_text()
