"""A competition (issue 36 item 7), with real processes: router, registry, runner, grader.

A roster of two teams and a solo student; each hands in a controller (one
works, one raises, one loops), graded as usual. The teacher runs a
competition with `wart course competition run --wait`: each team's entry runs
in its own heat, a student watching sees the standings as each heat ends, the
ranking is in the score's order with each entry's cause, `show` prints where
the recordings are and each is a readable MCAP of the heat's run.
"""

from __future__ import annotations

import json
import queue
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from common import keys
from common.client.grader_client import GraderClient
from common.lab_errors import LabError
from common.messages import Standings
from common.recording.reader import read_recording
from common.recording.replay import Timeline
from common.service import close_session
from tests.conftest import Procs, Router, needs_sandbox
from tests.integration.test_grading import COURSE, add_assignment, assignment_toml, source
from tests.kit.agentkit import start_runner, together
from tests.kit.lab import PASSWORD, USERS, ProcessLab, make_lab
from tests.kit.procs import REPO
from tests.kit.procs import wart as lab_wart

pytestmark = [pytest.mark.timeout(600), needs_sandbox]


def wart(*args: str) -> subprocess.CompletedProcess[str]:
    return lab_wart(*args, timeout=400)


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path, users={**USERS, "dan": "student"})
    lab.start_registry()
    roster = tmp_path / "class.csv"
    # Two teams (red: alice and dan; blue: bob) and carol on her own.
    roster.write_text(
        "user,name,role,team\nalice,Alice A,student,red\ndan,Dan D,student,red\n"
        "bob,Bob B,student,blue\ncarol,Carol C,student,\nida,Ida I,teacher,\n"
    )
    done = wart("users", "--db", str(lab.db_path), "import", str(roster), "--course", COURSE)
    assert done.returncode == 0, done.stderr
    together(lambda: start_runner(lab), lab.start_grader)
    yield lab


def test_a_competition_of_two_teams_and_a_solo_student(lab: ProcessLab, tmp_path: Path) -> None:
    # Someone who never logged in listens to everything the grader puts: no student's
    # name (nor so their scores) may be in it; each page asks for what it may see.
    spy = lab.zsession()
    heard: list[bytes] = []
    spy.declare_subscriber(
        f"{keys.realm_root(lab.realm)}/grader/**", lambda s: heard.append(s.payload.to_bytes())
    )
    add_assignment(lab, tmp_path, "reach-goal", episodes="1", seeds="[3]")
    add_assignment(lab, tmp_path, "empty-one", episodes="1", seeds="[3]")
    pw = tmp_path / "pw"
    pw.write_text(PASSWORD)
    net = lab.net_args()

    # Entries: each team's latest graded submission (dan's raising one was before alice's).
    handed = (("dan", "raises"), ("alice", "works"), ("bob", "loops"), ("carol", "raises"))
    for user, name in handed:
        with lab.client(user) as client:
            grader = GraderClient(client)
            sub = grader.submit("reach-goal", source(name), f"{name}.py").submission
            assert grader.wait_graded("reach-goal", sub, 180).status == "graded"

    # Refused: a student; an assignment with no graded submission at all.
    run = ("course", "competition", "run")
    by_alice = wart(*run, "reach-goal", "--user", "alice", "--password-file", str(pw), *net)
    assert by_alice.returncode == 1
    assert f"only the teachers of {COURSE} run a competition" in by_alice.stderr
    empty = wart(*run, "empty-one", "--user", "ida", "--password-file", str(pw), *net)
    assert empty.returncode == 1
    assert f"no entries: no team of {COURSE} has a graded submission to empty-one" in empty.stderr

    # bob watches the standings while the teacher runs it and waits for the end.
    seen: queue.Queue[Standings] = queue.Queue()
    with lab.client("bob") as client:
        stop = GraderClient(client).watch_standings("final", seen.put)
        try:
            done = wart(
                *run, "reach-goal", "--name", "final", "--wait", "300", "--user", "ida",
                "--password-file", str(pw), *net,
            )  # fmt: skip
            assert done.returncode == 0, done.stderr
            updates: list[Standings] = []
            while not updates or updates[-1].status != "finished":
                updates.append(seen.get(timeout=30))
        finally:
            stop()
    assert "competition final on reach-goal" in done.stdout and "finished" in done.stdout
    # A heat was seen ending with others still waiting: live, heat by heat.
    assert any(
        u.status == "running"
        and any(e.cause != "waiting" for e in u.entries)
        and any(e.cause == "waiting" for e in u.entries)
        for u in updates
    ), updates
    final = updates[-1]
    assert final.entries[0].team == "red"
    assert {e.team for e in final.entries} == {"red", "blue", "carol"}
    by_team = {e.team: e for e in final.entries}
    assert by_team["red"].user == "alice" and by_team["red"].rank == 1
    assert by_team["red"].cause == "ok" and by_team["red"].score == pytest.approx(99.6, abs=0.1)
    assert by_team["blue"].cause == "timeout"
    assert by_team["blue"].detail.startswith("the entry's controller: it did not answer in time")
    assert by_team["carol"].cause == "exception"
    assert by_team["carol"].detail == (
        "the entry's controller: line 13: ZeroDivisionError: division by zero on purpose"
    )
    assert by_team["blue"].rank == by_team["carol"].rank == 2  # both -3: a shared rank
    assert sorted(e.heat for e in final.entries) == [1, 2, 3]

    # show: the standings and where each heat's recording is; each reads back.
    shown = wart(
        "course", "competition", "show", "final", "--user", "carol", "--password-file", str(pw),
        *net,
    )  # fmt: skip
    assert shown.returncode == 0, shown.stderr
    assert "1. red" in shown.stdout and "exception: the entry's controller: line 13" in shown.stdout
    for e in final.entries:
        assert f"recording: {e.recording}" in shown.stdout
        recording = read_recording(e.recording)
        assert recording.info is not None and recording.info.user == e.user
        assert recording.info.mode == "competition"
        assert recording.end is not None and recording.end.reason.startswith(e.cause)
        assert recording.poses, "the heat's path is recorded"
        assert recording.source is not None and not recording.truncated
    assert heard  # the grader's announcements of gradings, heats, the end
    for student in (b"alice", b"bob", b"carol", b"dan"):
        assert not [p for p in heard if student in p], f"{student!r} in a put anyone reads"
    close_session(spy)
    red = read_recording(by_team["red"].recording)
    path = red.poses
    assert path[-1].record.pose.position.x > path[0].record.pose.position.x  # it drove forward
    # Replayable: the world it ran in and its frames, through the replay's own lookups.
    assert red.snapshot is not None and "k1" in red.snapshot.rows
    replay = Timeline(red)
    assert replay.duration == pytest.approx(3.0, abs=0.2)
    start, end = replay.at(0.0), replay.at(replay.duration)
    k1 = end.frame.rows.index("k1")
    assert end.frame.x[k1] > start.frame.x[k1] + 50  # the robot moves in the replay

    with lab.client("ida") as client, pytest.raises(LabError, match="exists already"):
        GraderClient(client).run_competition("reach-goal", "final")

    # Heats of several entries: red and blue in one world at once, each on its own robot,
    # driving at each other. A heat bigger than the map's robots is refused.
    duel = json.loads((REPO / "maps" / "empty.json").read_text())
    duel["agents"].append({"id": "k2", "type": "khepera", "x": 800, "y": 200})
    (tmp_path / "duel.json").write_text(json.dumps(duel))
    toml = tmp_path / "duel.toml"
    toml.write_text(
        assignment_toml("duel", map='"duel.json"', episodes="1", seeds="[3]", time_limit="2.0")
        + "\n[[start]]\nx = 600\ny = 500\nheading_deg = 180\n"
    )
    added = wart("course", "--db", str(lab.db_path), "assignment", "add", str(toml))
    assert added.returncode == 0, added.stderr
    for user in ("alice", "bob"):
        with lab.client(user) as client:
            grader = GraderClient(client)
            sub = grader.submit("duel", source("works"), "works.py").submission
            assert grader.wait_graded("duel", sub, 180).status == "graded"
    three = wart(*run, "duel", "--per-heat", "3", "--user", "ida", "--password-file", str(pw), *net)
    assert three.returncode == 1
    assert "the map duel.json has 2 robot(s) (k1, k2): a heat holds at most 2" in three.stderr
    done = wart(
        *run, "duel", "--name", "pairs", "--per-heat", "2", "--wait", "300", "--user", "ida",
        "--password-file", str(pw), *net,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    with lab.client("carol") as client:
        pairs = GraderClient(client).standings("pairs")
    assert pairs.status == "finished" and pairs.heats == 1
    by_team = {e.team: e for e in pairs.entries}
    assert by_team["red"].heat == by_team["blue"].heat == 1
    # Places in the teams' name order: blue on the assignment's robot, red on the other.
    assert by_team["blue"].detail.startswith("on k1: ran its 2 simulated s")
    assert by_team["red"].detail.startswith("on k2: ran its 2 simulated s")
    for e in pairs.entries:  # they met: a robot collision counted for each
        assert "collision(s) with another robot" in e.detail, e.detail
    assert by_team["red"].recording == by_team["blue"].recording  # one heat, one recording
    heat = read_recording(by_team["red"].recording)
    assert heat.snapshot is not None and {"k1", "k2"} <= set(heat.snapshot.rows)
    assert {p.record.frame_id for p in heat.poses} == {"arena"} and len(heat.poses) > 20
    replay = Timeline(heat)
    k2 = replay.at(0.0).frame.rows.index("k2")
    assert replay.at(replay.duration).frame.x[k2] < replay.at(0.0).frame.x[k2]  # it drove
