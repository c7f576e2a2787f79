"""The Class folder's model: rows joined with the arena's runs, keys turned into speeds."""

from __future__ import annotations

from common.messages import ClassRow, ClassTable
from viewers.web.adapters import AgentStatus
from viewers.web.class_table import (
    KeyHold,
    format_class,
    live_runs,
    parse_keys,
    speeds_for,
    students,
)


def table() -> ClassTable:
    return ClassTable(
        course="robotics-26",
        title="Robotics",
        rows=[
            ClassRow(user="alice", name="Alice A", assignment="reach-goal", submission="s1",
                     status="graded", submitted_at=0.0, score=99.62, submissions=1),
            ClassRow(user="bob", name="Bob | B", assignment="reach-goal", submission="s2",
                     status="running", submitted_at=0.0,
                     failure="exception: line 13: ZeroDivisionError"),
            ClassRow(user="carol", name="", assignment="reach-goal", submission="s3",
                     status="queued", submitted_at=0.0, queue_place=2),
            ClassRow(user="dora", name="dora"),
        ],
    )  # fmt: skip


def test_each_student_is_a_row_with_status_queue_score_failure_and_live_run() -> None:
    runs = live_runs(
        [
            AgentStatus("k1", holder="bob", queue=0, slot_left_s=41.6, taken_by="ida"),
            AgentStatus("k2", holder=None, queue=0),
            AgentStatus("k3", holder="carol", queue=1, slot_left_s=None),
        ]
    )
    assert set(runs) == {"bob", "carol"}
    text = format_class([table()], runs)
    lines = text.splitlines()
    assert lines[0] == "**Robotics** (robotics\\-26): 4 student(s)"
    alice, bob, carol, dora = lines[4:8]
    assert alice.startswith("| Alice A \\(alice\\) | reach\\-goal ")
    assert "| graded | - | 99.62 | - | - |" in alice
    # A name with a pipe stays in its cell; grading is what a running submission does.
    assert bob.startswith("| Bob \\| B \\(bob\\) |")
    assert "| grading | - | - | exception: line 13: ZeroDivisionError |" in bob
    assert bob.endswith("| k1, 42 s left, taken over by ida |")
    assert "| carol |" in carol and "| queued | 2 | - | - | k3 |" in carol
    assert dora == "| dora | - | no submission | - | - | - | - |"
    assert students([table()]) == ("alice", "bob", "carol", "dora")
    assert format_class([], {}) == "_You teach no course here._"


def test_held_keys_become_wheel_speeds_and_nothing_held_stops() -> None:
    assert parse_keys("fl 17") == "fl"
    assert parse_keys("lf 18") == "fl"  # order does not matter
    assert parse_keys(" 19") == "" and parse_keys("") == ""
    assert parse_keys("xz<script> 3") == "" and parse_keys("frrrrr 1") == ""  # not the page's
    assert speeds_for("") == (0, 0)
    assert speeds_for("f") == (12, 12)
    assert speeds_for("b") == (-12, -12)
    assert speeds_for("l") == (-5, 5) and speeds_for("r") == (5, -5)
    assert speeds_for("fr") == (12, 5) and speeds_for("fl") == (5, 12)
    assert speeds_for("bf") == (0, 0)  # opposite keys cancel
    assert speeds_for("blr") == (-12, -12)


def test_the_deadman_stops_a_robot_whose_page_went_quiet_with_keys_held() -> None:
    keys = KeyHold(deadman_s=0.6)
    assert keys.update("f 1", now=10.0) == (12, 12)
    assert keys.update("f 2", now=10.2) is None  # a heartbeat: nothing to change
    assert not keys.expired(now=10.7)  # 0.5 s since the last word
    assert keys.expired(now=10.9)  # 0.7 s: the page is gone, stop
    assert not keys.expired(now=11.5) and keys.held == ""  # once
    assert keys.update("fr 3", now=12.0) == (12, 5)  # the page is back
    assert keys.update(" 4", now=12.1) == (0, 0)  # released: stop at once
    assert not keys.expired(now=20.0)  # nothing held: no deadman to fire
