"""The editor's Check: each planted error is named with its line; the examples are clean."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.controller.advice import check_source

EXAMPLES = sorted((Path(__file__).parents[4] / "examples").glob("*.py"))
assert EXAMPLES, "the examples folder was not found"

GOOD = """\
from common.controller import Controller, Khepera


class Go(Controller):
    def initialize(self, robot: Khepera) -> None:
        self.bot = robot

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(5, 5)
        self.bot.set_leds(True, False)
"""


def lines_of(source: str) -> list[str]:
    return [str(p) for p in check_source(source.encode())]


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_every_example_passes(path: Path) -> None:
    assert check_source(path.read_bytes(), path.name) == []


def test_a_clean_controller_passes() -> None:
    assert lines_of(GOOD) == []


def test_a_syntax_error_names_its_line() -> None:
    bad = GOOD.replace("robot.set_speeds(5, 5)", "robot.set_speeds(5, 5")
    found = lines_of(bad)
    assert len(found) == 1
    assert found[0].startswith("line 9: syntax error") or found[0].startswith("line 10: syntax")


def test_an_unknown_robot_call_names_its_line_and_the_right_name() -> None:
    bad = GOOD.replace("robot.set_speeds(5, 5)", "robot.set_speed(5, 5)")
    assert lines_of(bad) == [
        "line 9: robot.set_speed does not exist on Khepera (did you mean set_speeds?)"
    ]


def test_a_robot_kept_in_self_is_checked_too_whatever_the_parameter_is_called() -> None:
    before = "robot: Khepera) -> None:\n        self.bot = robot"
    bad = GOOD.replace(before, "r):\n        self.bot = r")
    bad = bad.replace("self.bot.set_leds(True, False)", "self.bot.leds_on()")
    assert lines_of(bad) == ["line 10: self.bot.leds_on does not exist on Khepera"]


def test_no_controller_class_is_reported() -> None:
    found = lines_of("def do_work(robot):\n    robot.set_speeds(1, 1)\n")
    assert len(found) == 1
    assert "defines no controller" in found[0]


def test_a_controller_without_do_work_names_the_class_line() -> None:
    src = "from common.controller import Controller\n\n\nclass Idle(Controller):\n    pass\n"
    assert lines_of(src) == ["line 4: class Idle has no do_work(self, robot) method"]


@pytest.mark.parametrize(
    ("statement", "why"),
    [
        ("import socket", "import socket is not allowed: the sandbox has no network"),
        ("from urllib import request", "import urllib is not allowed: the sandbox has no network"),
        ("import subprocess", "import subprocess is not allowed: a controller may not start"),
        ("import numpy as np", "import numpy is not available in the sandbox"),
        ("from common import files", "import common.files is not available in the sandbox"),
        ("x = __import__('ctypes')", "import ctypes is not allowed: native code"),
    ],
)
def test_a_forbidden_import_names_its_line(statement: str, why: str) -> None:
    src = GOOD.replace("from common.controller", f"{statement}\nfrom common.controller")
    found = lines_of(src)
    assert len(found) == 1
    assert found[0].startswith(f"line 1: {why}")


def test_several_problems_come_sorted_by_line() -> None:
    src = GOOD.replace("robot.set_speeds(5, 5)", "robot.go()").replace(
        "from common.controller", "import socket\nfrom common.controller"
    )
    found = lines_of(src)
    assert [f.split(":")[0] for f in found] == ["line 1", "line 10"]
