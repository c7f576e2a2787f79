"""Real robots' twins travel as messages: the registry (a real process, real SQLite) serves
them on ``registry/twins`` to whoever may read them, keeps what an owner or admin saves.

``wart twin`` saves, lists and shows through the registry; a student who owns no arena
reads nothing and saves nothing (the refusal is in the audit trail); a twin file is
checked by the registry as well as by the tool; a runner's account reads the twin in
force (kept a few seconds), and a registry that does not answer leaves the datasheet's
model with the reason, for the dry run's model line.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from common.auth import load_identity_key
from common.lab_errors import LabError
from common.robots import registry
from common.robots.robotfile import parse
from services.commands import twin as twin_cli
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow
from services.runner.twins import TwinLookup
from tests.conftest import Procs, Router, wait_for
from tests.kit.agentkit import start_agent_context, start_engine
from tests.kit.lab import PASSWORD, ProcessLab, audit_trail, make_lab
from tests.unit.common.twin.test_twin_store import DAY, FITTED_AT, calibration, document

pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]


@pytest.fixture
def lab(
    router: Router, procs: Procs, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> ProcessLab:
    monkeypatch.setenv("WART_PASSWORD", PASSWORD)
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    return lab


def test_wart_twin_saves_lists_and_shows_through_the_registry(
    lab: ProcessLab, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def twin(user: str, *args: str) -> int:
        return twin_cli.main([*lab.net_args(), "--user", user, *args])

    good, bad = tmp_path / "k1.json", tmp_path / "bad.json"
    good.write_text(calibration().to_json("carol", FITTED_AT))
    bad.write_text(json.dumps(document(robot="")))
    assert twin("admin", "save", str(bad)) == 1  # refused by the tool, before any login
    assert "refused, nothing kept" in capsys.readouterr().err
    assert twin("ida", "list") == 0  # a teacher reads
    assert "no twin is kept" in capsys.readouterr().out
    # A student who owns no arena reads nothing and keeps nothing.
    assert twin("alice", "list") == 1
    assert "alice may not read the robots' twins" in capsys.readouterr().err
    assert twin("alice", "save", str(good), "--arena", "lab") == 1
    assert "arena lab is not yours (or not running)" in capsys.readouterr().err
    assert twin("admin", "save", str(good)) == 0  # a lab admin needs no arena
    kept = "as k1's twin (for no arena in particular) v1 (in force)"
    assert f"kept k1's twin fitted {DAY} by carol {kept}" in capsys.readouterr().out
    assert twin("ida", "show", "k2") == 1
    assert "no twin of k2" in capsys.readouterr().err
    robot_file = tmp_path / "twin-k1.toml"
    assert twin("ida", "show", "k1", "--robot-file", str(robot_file)) == 0
    out = capsys.readouterr().out
    assert "v1: fitted" in out and "saved" in out and "by admin" in out, out
    assert "in force (v1): scale_left 0.96, scale_right 0.99, wheel_base_mm 55" in out, out
    # An arena without a twin of its own for k1 uses the one kept for no arena.
    assert twin("ida", "show", "k1", "--arena", "lab") == 0
    out = capsys.readouterr().out
    assert "k1's twin in lab: the one kept for no arena, 1 version(s)" in out, out
    # The robot file a lab loads: the shipped Khepera with the fitted drive.
    spec = parse(robot_file.read_bytes(), robot_file.name, registry.build().components)
    assert spec.name == "twin-k1" and spec.drive.wheel_scale == (0.96, 0.99)
    with lab.client("admin") as admin:
        # The registry checks a document itself: a client that skips the check gains nothing.
        with pytest.raises(LabError, match="refused, nothing kept"):
            admin.twins.save(json.dumps(document(robot="k1", fitted_by="")), "k1")
        lines = audit_trail(admin, action="twin_save")
    assert [(e.actor, e.outcome, e.target) for e in lines] == [
        ("admin", "ok", "twin/k1"),
        ("alice", "refused", "twin/lab/k1"),
    ]


def test_a_runner_reads_the_twin_in_force_and_says_when_the_registry_is_gone(
    lab: ProcessLab,
) -> None:
    key = load_identity_key(lab.account("runner-svc"))
    with lab.client() as runner, lab.client("admin") as admin:
        runner.login_with_key("runner-svc", key)
        seal = runner._seal  # the runner seals with its service session, as a LabClient does
        lookup = TwinLookup(runner.z, lab.realm, seal)
        assert lookup.twin_of("east", "k1").twin is None
        assert lookup.twin_of("east", "k1").why_not == ""
        admin.twins.save(calibration(scale_left=0.96).to_json("carol", FITTED_AT), "k1", "east")
        assert lookup.twin_of("east", "k1").twin is None  # the answer kept a few seconds
        fresh = TwinLookup(runner.z, lab.realm, seal, cache_s=0.0)
        got = fresh.twin_of("east", "k1").twin
        assert got is not None and got.drive.scale_left == 0.96 and got.fitted_by == "carol"
        admin.twins.save(calibration(scale_left=0.95).to_json("dave", FITTED_AT), "k1", "east")
        got = fresh.twin_of("east", "k1").twin
        assert got is not None and got.drive.scale_left == 0.95  # the newest is in force
        reply = admin.twins.of("k1", "east")
        assert reply.versions == 2 and reply.history == [] and reply.arena == "east"
        # Another arena's k1 is another robot: east's twin is not its.
        assert fresh.twin_of("west", "k1").twin is None
        admin.twins.save(calibration(scale_left=1.04).to_json("joe", FITTED_AT), "k1", "west")
        got = fresh.twin_of("west", "k1").twin
        assert got is not None and got.fitted_by == "joe"
        assert [(t.arena, t.robot, t.versions) for t in admin.twins.robots()] == [
            ("east", "k1", 2), ("west", "k1", 1),
        ]  # fmt: skip
        lab.registry.stop()
        gone = fresh.twin_of("east", "k1")
    assert gone.twin is None and gone.why_not == "the registry did not give k1's twin"


def test_an_owner_keeps_only_their_arenas_robots_and_a_course_teacher_reads_its_arenas(
    lab: ProcessLab,
) -> None:
    """ida owns the arena ``arena`` (k0..k3) and teaches the course robotics with carol, a
    student account made a teacher of it; bob teaches another course."""
    db = RegistryDB(lab.db_path)
    courses = CourseStore(db)
    courses.import_roster("robotics", [RosterRow(1, "ida", role="teacher"),
                                       RosterRow(2, "carol", role="teacher")])  # fmt: skip
    courses.import_roster("other", [RosterRow(1, "bob", role="teacher")])
    db.close()
    start_engine(lab, "foraging")
    start_agent_context(lab, ctx="arena")
    k1 = calibration("k1").to_json("ida", FITTED_AT)
    k9 = calibration("k9").to_json("ida", FITTED_AT)
    with lab.client("ida") as ida, lab.client("carol") as carol, lab.client("bob") as bob:
        # The registry learns the arena's robots from the context (within a few seconds).
        def robots_known() -> bool:
            try:
                ida.twins.save(k9, "k9", "arena")
            except LabError as exc:
                # Refused before too, while the registry knew no robot of it: "none yet".
                return "has no robot k9 (its robots: k0" in str(exc)
            raise AssertionError("k9's twin was kept for an arena without k9")

        wait_for(robots_known, 30, "the registry knowing the arena's robots")
        with pytest.raises(LabError) as refused:
            ida.twins.save(k9, "k9", "arena")
        assert "ida may not keep k9's twin: arena arena has no robot k9 (its robots: k0, k1, " in (
            str(refused.value)
        )
        assert ida.twins.save(k1, "k1", "arena").version == 1  # a robot of her arena
        with lab.client("admin") as admin:
            admin.twins.save(calibration("k2").to_json("admin", FITTED_AT), "k2")  # no arena
            trail = audit_trail(admin, action="twin_save")
        assert ("ida", "refused", "twin/arena/k9") in [
            (e.actor, e.outcome, e.target) for e in trail
        ]
        # carol teaches the arena's course: she reads its twins, and only those.
        reply = carol.twins.of("k1", "arena")
        assert reply.current is not None and reply.arena == "arena"
        assert [(t.arena, t.robot) for t in carol.twins.robots()] == [("arena", "k1")]
        with pytest.raises(
            LabError,
            match="carol may not read the twins of arena east: it is "
            r"not an arena of a course carol teaches \(those running now: arena\)",
        ):
            carol.twins.of("k1", "east")  # fmt: skip
        with pytest.raises(
            LabError, match="carol may not keep k1's twin: arena arena is not yours"
        ):
            carol.twins.save(k1, "k1", "arena")  # fmt: skip
        # bob teaches another course: none of the arena's twins.
        with pytest.raises(LabError, match="bob may not read the robots' twins"):
            bob.twins.of("k1", "arena")
