"""A teacher's grader function (issue 36, item 2), with real processes: router, registry,
runner, grader.

The teacher adds assignments naming a grader file (`wart course assignment add`, which
refuses a bad one whole); a student's submissions are graded on the runner, the grader
run after each episode in the runner's sandbox; its metrics join the score rule. A
grader that raises, loops or floods is the teacher's fault: the student reads why (the
grader's file and line), is not charged, and the teacher sees it in `wart course`.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
from pathlib import Path

import pytest

from common.client.grader_client import GraderClient
from services.grader import course_cli
from tests.integration.test_grading import assignment_toml, lab, source, wart  # noqa: F401
from tests.kit.lab import ProcessLab

pytestmark = pytest.mark.timeout(300)
GRADERS = Path(__file__).parent / "grading" / "graders"
WOBBLE = '100 * reached("goal") - metric("wobble")'


def course(*args: str) -> subprocess.CompletedProcess[str]:
    """`wart course ...` in this process (its own code, on the lab's database file): a
    subprocess per call cost a second or two of imports each."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = course_cli.main(list(args))
    return subprocess.CompletedProcess(["wart", "course", *args], code, out.getvalue(),
                                       err.getvalue())  # fmt: skip


def add(on: ProcessLab, tmp: Path, name: str, grader: str, **fields: str) -> None:
    """An assignment of one 1 s episode, scored with the grader's wobble."""
    (tmp / grader).write_bytes((GRADERS / grader).read_bytes())
    path = tmp / f"{name}.toml"
    text = assignment_toml(
        name,
        rule=WOBBLE,
        grader=f'"{grader}"',
        episodes="1",
        seeds="[1]",
        time_limit="1.0",
        **fields,
    )
    path.write_text(text)
    done = course("--db", str(on.db_path), "assignment", "add", str(path))
    assert done.returncode == 0, done.stderr
    assert f"grader {grader} stored with it" in done.stdout


def test_a_teachers_grader_scores_and_its_failures_are_the_teachers(
    lab: ProcessLab,  # noqa: F811
    tmp_path: Path,
) -> None:
    db = str(lab.db_path)
    # A grader that does not parse, or defines no grade(), is refused whole: nothing written.
    (tmp_path / "broken.py").write_text("def grade(episode)\n    return {}\n")
    (tmp_path / "nograde.py").write_text("def score(episode):\n    return {}\n")
    bad = tmp_path / "bad.toml"
    for grader, problem in (
        ("broken.py", "grader: broken.py, line 1: syntax error: expected ':'"),
        ("nograde.py", "grader: nograde.py defines no grade(episode) function at its top level"),
        ("missing.py", "grader: cannot read missing.py (No such file or directory)"),
    ):
        bad.write_text(assignment_toml("bad", rule=WOBBLE, grader=f'"{grader}"'))
        done = course("--db", db, "assignment", "add", str(bad))
        assert done.returncode == 1 and problem in done.stderr, done.stderr
        assert "refused (nothing written)" in done.stderr
    bad.write_text(assignment_toml("bad", rule=WOBBLE))  # metric() with no grader
    done = course("--db", db, "assignment", "add", str(bad))
    assert "reads metric('wobble'), but the assignment names no grader" in done.stderr
    assert " bad " not in course("--db", db, "assignments").stdout

    add(lab, tmp_path, "wobbly", "wobble.py")
    add(lab, tmp_path, "g-raises", "raises.py", quota="1")
    add(lab, tmp_path, "g-loops", "loops.py", grader_time_limit="2")
    add(lab, tmp_path, "g-floods", "floods.py")

    with lab.client("alice") as client:
        grader = GraderClient(client)
        subs = {
            a: grader.submit(a, source("works"), "works.py").submission
            for a in ("wobbly", "g-raises", "g-loops", "g-floods")
        }
        done_ = {a: grader.wait_graded(a, s, 120) for a, s in subs.items()}
        # The rule read the grader's metric; the metric shows beside ours.
        good = done_["wobbly"]
        assert good.status == "graded" and good.counted, good
        [episode] = good.episodes
        assert episode.cause == "ok"
        wobble = episode.metrics["wobble"]
        assert episode.metrics["samples"] == 11  # 1 simulated s: a pose each 0.1 s, and t=0
        assert episode.score == pytest.approx(100 - wobble, abs=1e-3)
        # Each failure is the teacher's: said with the grader's file and line; not charged.
        # The loop is caught by the hang watchdog after 1 s, which says where it was; on a
        # starved machine (load 13 on 2 cores, seen) the sandbox's start can eat the 2 s
        # before the watchdog looks, and the wall-clock limit says so instead.
        for name, said in (
            ("g-raises", ("raises.py, line 3: ZeroDivisionError: division by zero",)),
            (
                "g-loops",
                (
                    "loops.py: hung: grade() did not return for 1 s; it was at loops.py:",
                    "loops.py: grade() did not return in 2 s",
                ),
            ),
            ("g-floods", ("floods.py: killed: output flood",)),
        ):
            sub = done_[name]
            assert sub.status == "failed" and not sub.counted and sub.mean is None, sub
            told = [s for s in said if sub.message.startswith(f"the teacher's grader failed: {s}")]
            assert told, sub.message
            assert sub.message.endswith("not counted against your quota; your teacher is told")
            [episode] = sub.episodes
            assert episode.cause == "grader" and told[0] in episode.detail
        assert done_["g-raises"].episodes[0].error_line == 3
        # A quota of one, and the failed run did not use it.
        again = grader.submit("g-raises", source("works"), "works.py")
        assert again.used == 1
        assert grader.wait_graded("g-raises", again.submission, 120).status == "failed"
    listing = course("--db", db, "assignments")
    assert "grader raises.py: 2 submission(s) it failed" in listing.stdout, listing.stdout
    assert "latest: the teacher's grader failed: raises.py, line 3" in listing.stdout
    assert "grader wobble.py: 0 submission(s) it failed" in listing.stdout
