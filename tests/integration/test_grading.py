"""A class graded automatically (issue 36), with real processes: router, registry, runner, grader.

The teacher imports a roster and adds assignments with `wart users import` and
`wart course assignment add`; students submit through the grader (one with
`wart submit --wait`), whose episodes run on the runner's sandbox; scores,
causes, refusals and the leaderboard are what the students and the teacher see.
"""

from __future__ import annotations

import contextlib
import subprocess
import time
from pathlib import Path

import pytest

from common.client.grader_client import GraderClient
from common.lab_errors import LabError
from common.messages import GradingChanged
from common.recording import read_recording
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import start_runner
from tests.kit.courses import COURSE, assignment_toml, import_roster, start_grading_lab
from tests.kit.lab import PASSWORD, ProcessLab, make_lab
from tests.kit.procs import wart as lab_wart

pytestmark = [pytest.mark.timeout(600), needs_sandbox]
CONTROLLERS = Path(__file__).parent / "grading"


def wart(lab: ProcessLab, *args: str) -> subprocess.CompletedProcess[str]:
    return lab_wart(*args)


def add_assignment(lab: ProcessLab, tmp: Path, name: str, **fields: str) -> None:
    path = tmp / f"{name}.toml"
    path.write_text(assignment_toml(name, **fields))
    done = wart(lab, "course", "--db", str(lab.db_path), "assignment", "add", str(path))
    assert done.returncode == 0, done.stderr
    assert f"assignment {name} added in course {COURSE}" in done.stdout


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    roster = (
        "user,name,role\nalice,Alice A,student\nbob,Bob B,student\ncarol,Carol C,student\n"
        "ida,Ida I,teacher\n"
    )
    return start_grading_lab(router, procs, tmp_path, roster)


def source(name: str) -> bytes:
    return (CONTROLLERS / f"{name}.py").read_bytes()


def test_three_students_graded_with_causes_refusals_and_a_leaderboard(
    lab: ProcessLab, procs: Procs, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    # A bad file is refused whole, with its field; nothing is written.
    bad = tmp_path / "bad.toml"
    bad.write_text(assignment_toml("bad", time_limit="-1").replace("reached(", "eval("))
    done = wart(lab, "course", "--db", str(lab.db_path), "assignment", "add", str(bad))
    assert done.returncode == 1
    assert "time_limit: -1 is not within 0.5..300" in done.stderr
    assert "score.rule: column 7: unknown function eval()" in done.stderr
    add_assignment(lab, tmp_path, "reach-goal", hide_until_deadline="true")
    add_assignment(lab, tmp_path, "one-a-day", quota="1", episodes="1", seeds="[7]")
    add_assignment(
        lab, tmp_path, "closed", opens="2025-01-01T00:00:00Z", deadline="2025-02-01T00:00:00Z"
    )
    add_assignment(lab, tmp_path, "future", opens="2098-01-01T00:00:00Z")

    # The teacher's view, live: every change is published (no score in it).
    stack = contextlib.ExitStack()
    request.addfinalizer(stack.close)
    watcher = GraderClient(stack.enter_context(lab.client("ida")))
    changes: list[GradingChanged] = []
    stack.callback(watcher.watch_changes(changes.append))

    subs: dict[str, str] = {}
    for user, name in (("carol", "raises"), ("bob", "loops")):
        with lab.client(user) as client:
            accepted = GraderClient(client).submit("reach-goal", source(name), f"{name}.py")
            assert accepted.quota == 5 and accepted.used == 1
            subs[user] = accepted.submission
    # alice uses the command line and waits for her score there.
    works = tmp_path / "works.py"
    works.write_bytes(source("works"))
    pw = tmp_path / "pw"
    pw.write_text(PASSWORD)
    cli = procs.start(
        "submit",
        ["submit", "--assignment", "reach-goal", "--user", "alice", "--password-file", str(pw),
         "--wait", "300", str(works), *lab.net_args()],
    )  # fmt: skip
    assert cli.popen.wait(320) == 0, cli.output()
    out = cli.output()
    assert "submitted s" in out and "1 of 5 graded runs in the last 24 h" in out
    assert "graded  mean 99.6" in out, out
    assert "episode 1 (seed 2):" in out and "ok: ran its 3 simulated s" in out

    with lab.client("ida") as client:  # the teacher sees everyone's
        grader = GraderClient(client)
        raised = grader.wait_graded("reach-goal", subs["carol"], 120)
        looped = grader.wait_graded("reach-goal", subs["bob"], 120)
        board = grader.leaderboard("reach-goal")
    assert raised.status == "graded" and raised.counted
    for e in raised.episodes:
        assert e.cause == "exception" and e.error_line == 13
        assert (
            e.detail == "your controller: line 13: ZeroDivisionError: division by zero on purpose"
        )
        assert e.score == pytest.approx(-3.0)  # never reached the goal: time_to is the limit
        # The student reads where the points went, and what their controller printed.
        assert [t for t, _ in e.terms] == [
            '100 * reached("goal")',
            "- 5 * collisions()",
            '- time_to("goal")',
        ]
        assert sum(v for _, v in e.terms) == pytest.approx(e.score)
        assert any("ZeroDivisionError" in line for line in e.output), e.output
    for e in looped.episodes:
        assert e.cause == "timeout" and e.score == pytest.approx(-3.0)
        assert e.detail.startswith("your controller: it did not answer in time")
    assert board.hidden  # hidden from students until the deadline; the teacher sees it
    assert (board.entries[0].rank, board.entries[0].name) == (1, "Alice A")
    assert board.entries[0].score == pytest.approx(99.6, abs=0.1)
    assert {e.name for e in board.entries} == {"Alice A", "Bob B", "Carol C"}

    def steps(sub: str) -> list[str]:
        return [c.status for c in changes if c.submission == sub]

    try:
        wait_for(lambda: steps(subs["carol"]) == ["queued", "running", "graded"], 10, "changes")
    except AssertionError:
        seen = steps(subs["carol"])
        raise AssertionError(f"carol's changes, as the watch saw them: {seen}") from None
    assert {(c.course, c.assignment) for c in changes} == {(COURSE, "reach-goal")}
    (table,) = watcher.class_tables()  # the one course ida teaches
    rows = {r.user: r for r in table.rows}
    assert sorted(rows) == ["alice", "bob", "carol"]  # the students, not the teacher
    assert rows["carol"].failure.startswith("exception: your controller: line 13: ZeroDiv")
    assert rows["bob"].failure.startswith("timeout: your controller: it did not answer")
    assert rows["alice"].score == pytest.approx(99.6, abs=0.1) and not rows["alice"].failure
    assert {r.status for r in rows.values()} == {"graded"}

    # Each graded episode is replayable: its student (and a teacher) fetch its recording.
    with lab.client("carol") as client:
        grader = GraderClient(client)
        [mine] = grader.submissions("reach-goal")
        assert [e.replay for e in mine.episodes] == [True] * len(mine.episodes)
        got = grader.fetch_episode("reach-goal", subs["carol"], 1, tmp_path / "carol-1.mcap")
    rec = read_recording(got)
    assert rec.info is not None and (rec.info.user, rec.info.mode) == ("carol", "graded")
    assert rec.snapshot is not None and rec.frames, "a replay draws the world's frames"
    assert rec.source == source("raises")
    assert rec.end is not None and "ZeroDivisionError" in rec.end.reason
    assert any("ZeroDivisionError" in o.record.message for o in rec.output)
    with lab.client("ida") as client:  # a teacher replays any student's
        GraderClient(client).fetch_episode("reach-goal", subs["carol"], 0, tmp_path / "c0.mcap")

    with lab.client("bob") as client:
        grader = GraderClient(client)
        with pytest.raises(LabError, match=f"you have no submission {subs['carol']}"):
            grader.fetch_episode("reach-goal", subs["carol"], 0, tmp_path / "stolen.mcap")
        assert not (tmp_path / "stolen.mcap").exists()
        with pytest.raises(LabError, match=r"episode 9 of \S+ has no replay kept"):
            grader.fetch_episode("reach-goal", subs["bob"], 9, tmp_path / "none.mcap")
        assert grader.leaderboard("reach-goal").entries == []  # hidden for a student
        with pytest.raises(LabError, match="only the course's teachers see others' runs"):
            grader.submissions("reach-goal", user="alice")
        assert [s.submission for s in grader.submissions("reach-goal")] == [subs["bob"]]
        assert grader.class_tables() == []  # a student teaches nothing
        with pytest.raises(LabError, match=f"only the teachers of {COURSE} see its class"):
            grader.class_tables(COURSE)
        assert grader.set_pseudonym("reach-goal", "Loopy") == (
            f"you show as Loopy on {COURSE}'s leaderboards"
        )
    with lab.client("carol") as client:
        grader = GraderClient(client)
        with pytest.raises(LabError, match=f"the name 'loopy' is taken in {COURSE}"):
            grader.set_pseudonym("reach-goal", "loopy")
        with pytest.raises(LabError, match="is taken"):
            grader.set_pseudonym("reach-goal", "Alice A")  # another's roster name
        with pytest.raises(LabError, match="a pseudonym is 1 to 32 letters"):
            grader.set_pseudonym("reach-goal", "<b>bold</b>")
    with lab.client("alice") as client:
        grader = GraderClient(client)
        first = grader.submit("one-a-day", source("works"), "works.py")
        with pytest.raises(LabError, match=r"quota: 1 of 1 graded runs in the last 24 h"):
            grader.submit("one-a-day", source("works"), "works.py")
        with pytest.raises(LabError, match=r"the deadline of closed was 2025-02-01 00:00 UTC"):
            grader.submit("closed", source("works"), "works.py")
        with pytest.raises(LabError, match=r"future opens at 2098-01-01 00:00 UTC"):
            grader.submit("future", source("works"), "works.py")
        with pytest.raises(LabError, match="no assignment named nope"):
            grader.submit("nope", source("works"), "works.py")
        assert grader.wait_graded("one-a-day", first.submission, 120).status == "graded"
    board_cli = wart(
        lab, "leaderboard", "reach-goal", "--user", "ida", "--password-file", str(pw),
        *lab.net_args(),
    )  # fmt: skip
    assert board_cli.returncode == 0, board_cli.stderr
    assert "you see it as a teacher" in board_cli.stdout
    fetched = wart(
        lab, "submit", "--assignment", "reach-goal", "--user", "carol", "--password-file", str(pw),
        "--episode", subs["carol"], "0", "-o", str(tmp_path / "cli.mcap"), *lab.net_args(),
    )  # fmt: skip
    assert fetched.returncode == 0, fetched.stderr
    assert f"episode 0 of {subs['carol']} written to" in fetched.stdout
    assert read_recording(tmp_path / "cli.mcap").source == source("raises")
    typo = wart(lab, "submit", "--assignment", "reach-goal", "--user", "carol", "--episode",
                subs["carol"], "first")  # fmt: skip
    assert typo.returncode != 0
    assert "N is an episode's number (0, 1, ...), not 'first'" in typo.stderr
    assert "1. Alice A" in board_cli.stdout
    assert "Bob B (as Loopy)" in board_cli.stdout  # the teacher sees who is behind a pseudonym
    # one-a-day is not hidden: a student sees it, under the pseudonym alice chooses here.
    mine = wart(
        lab, "leaderboard", "one-a-day", "--user", "alice", "--password-file", str(pw),
        "--pseudonym", "Speedy", *lab.net_args(),
    )  # fmt: skip
    assert mine.returncode == 0, mine.stderr
    assert f"you show as Speedy on {COURSE}'s leaderboards" in mine.stdout
    assert "1. Speedy" in mine.stdout and "Alice" not in mine.stdout.split("\n", 2)[2]


def test_a_runner_killed_mid_grading_reruns_free(lab: ProcessLab, tmp_path: Path) -> None:
    add_assignment(lab, tmp_path, "long", time_limit="8.0", episodes="1", seeds="[1]", quota="1")
    runner = next(p for p in lab.procs.started if p.name == "runner")
    with lab.client("alice") as client:
        grader = GraderClient(client)
        sub = grader.submit("long", source("slow"), "slow.py").submission
        wait_for(
            lambda: grader.submissions("long", submission=sub)[0].status == "running", 60, "running"
        )
        time.sleep(2.0)  # the episode is on the runner now (8 simulated s take ~9 s there)
        runner.kill9()
        start_runner(lab)  # the lab brings one back (a supervisor would)
        graded = grader.wait_graded("long", sub, 180)
        assert graded.status == "graded", graded
        [episode] = graded.episodes
        assert episode.cause == "ok" and episode.lab_reruns >= 1
        assert "after a lab fault, free" in episode.detail
        assert "failed through the lab and ran again, free" in graded.message
        # Counted once: the quota of one is used by this submission, not by the lab's fault.
        with pytest.raises(LabError, match="quota: 1 of 1"):
            grader.submit("long", source("works"), "works.py")


def test_a_submission_the_lab_cannot_grade_is_not_counted(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    """No runner at all: every try is the lab's fault; the student is told, the quota kept."""
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    import_roster(lab, "user,name\nalice,Alice A\n")
    add_assignment(lab, tmp_path, "once", episodes="1", seeds="[1]", quota="1")
    lab.start_grader("--runner-wait", "0.5")
    with lab.client("alice") as client:
        grader = GraderClient(client)
        sub = grader.submit("once", source("works"), "works.py").submission
        failed = grader.wait_graded("once", sub, 120)
        assert failed.status == "failed" and not failed.counted and failed.mean is None
        assert failed.message.startswith("the lab could not grade it (no runner is alive")
        assert failed.message.endswith("not counted against your quota; submit again")
        [episode] = failed.episodes
        assert episode.cause == "lab" and episode.lab_reruns == 4
        # The quota of one is still whole: this submission is taken.
        again = grader.submit("once", source("works"), "works.py")
        assert again.used == 1 and again.quota == 1


def test_a_grader_killed_mid_grading_grades_it_at_its_next_start(
    lab: ProcessLab, tmp_path: Path
) -> None:
    add_assignment(lab, tmp_path, "long", time_limit="4.0", episodes="2", seeds="[1, 2]")
    grader_proc = next(p for p in lab.procs.started if p.name == "grader")
    with lab.client("carol") as client:
        grader = GraderClient(client)
        sub = grader.submit("long", source("slow"), "slow.py").submission

        def partial() -> list[int]:
            [now] = grader.submissions("long", submission=sub)
            return [e.episode for e in now.episodes]

        # The first episode's result is readable while the second runs: a partial result.
        wait_for(lambda: partial() == [0], 120, "the first episode's result")
        first = lab.db_path.parent / "graded" / "long" / "carol" / sub / "episode-00.mcap"
        kept_at = first.stat().st_mtime_ns
        grader_proc.kill9()
        lab.start_grader(name="grader-again")
        graded = grader.wait_graded("long", sub, 180)
        assert graded.status == "graded" and graded.counted
        assert [e.cause for e in graded.episodes] == ["ok", "ok"]
        assert len(grader.submissions("long")) == 1  # the same submission, not a second one
        # The episode scored before the kill is kept, not run again: its recording is the same.
        assert first.stat().st_mtime_ns == kept_at


def test_a_held_out_episode_is_shown_to_its_student_once_released(
    lab: ProcessLab, tmp_path: Path
) -> None:
    """Gradescope's hidden tests: the second episode's result waits for the teacher's release."""
    add_assignment(
        lab, tmp_path, "held-out", episodes="2", seeds="[1, 2]",
        visibility='["now", "after_release"]',
    )  # fmt: skip
    with lab.client("alice") as client:
        grader = GraderClient(client)
        sub = grader.submit("held-out", source("works"), "works.py").submission
        graded = grader.wait_graded("held-out", sub, 180)
        shown, held = graded.episodes
        assert shown.cause == "ok" and shown.score is not None and shown.replay
        assert (held.cause, held.score, held.output, held.terms, held.replay) == (
            "hidden", None, [], [], False,
        )  # fmt: skip
        assert held.detail == "shown when your teacher releases the results"
        assert graded.mean is None and graded.min is None  # the mean would give it away
        assert "score" not in graded.message and "mean is shown when" in graded.message
        board = grader.leaderboard("held-out")
        assert board.hidden and board.entries == []
        assert board.hidden_until == "shown when your teacher releases the results"
        with pytest.raises(LabError, match="episode 1 is shown when your teacher releases"):
            grader.fetch_episode("held-out", sub, 1, tmp_path / "early.mcap")
    with lab.client("ida") as client:  # the teacher sees it all before the release
        [seen] = GraderClient(client).submissions("held-out", user="alice")
        assert [e.cause for e in seen.episodes] == ["ok", "ok"] and seen.mean is not None

    released = wart(lab, "course", "--db", str(lab.db_path), "release", "held-out")
    assert released.returncode == 0, released.stderr
    assert "held-out: results released to its students" in released.stdout
    with lab.client("alice") as client:
        grader = GraderClient(client)
        [after] = grader.submissions("held-out")
        assert [e.cause for e in after.episodes] == ["ok", "ok"]
        assert after.mean == seen.mean and all(e.replay for e in after.episodes)
        assert not grader.leaderboard("held-out").hidden
    nope = wart(lab, "course", "--db", str(lab.db_path), "release", "no-such")
    assert nope.returncode == 1 and "no assignment named no-such" in nope.stderr
