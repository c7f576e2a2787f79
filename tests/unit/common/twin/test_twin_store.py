"""A real robot's twin kept in the lab's database: checked on the way in, versioned, shown.

A twin file from a user (``wart twin save``) or from ``wart calibrate --save`` is
checked field by field; the lab's database (real SQLite) keeps every version, the
newest in force; ``wart twin`` lists and shows them; the twin's robot file compiles
to a Khepera with the fitted drive.
"""

from __future__ import annotations

import json
import re
import sqlite3
import time
from pathlib import Path
from typing import Any

import pytest

from common.robots import registry
from common.robots.robotfile import RobotFileError, parse
from common.twin.fit import Calibration, Estimate
from common.twin.twinfile import TwinFileError, parse_twin
from services.lab.database import DbError, LabDatabase
from services.lab.twins_db import TwinStore

FITTED_AT = time.time() - 3 * 86400  # a file "not in the future" whatever the clock says
DAY = time.strftime("%Y-%m-%d", time.gmtime(FITTED_AT))


def calibration(robot: str = "k1", scale_left: float = 0.96) -> Calibration:
    def fitted(name: str, value: float, datasheet: float, unit: str = "") -> Estimate:
        return Estimate(name, value, 0.002, datasheet, unit, ["dance"])

    drive = [
        fitted("scale_left", scale_left, 1.0),
        fitted("scale_right", 0.99, 1.0),
        fitted("wheel_base_mm", 55.0, 53.0, "mm"),
        Estimate("latency_s", 0.0, None, 0.0, "s", [], "the commands changed 1 time(s)"),
    ]
    proximity = [fitted("ir2_gain", 1.1, 1.0), fitted("ir2_noise", 3.0, 4.0, "counts")]
    return Calibration(robot, ["dance"], drive, proximity)


def document(**changes: Any) -> dict[str, Any]:
    doc = json.loads(calibration().to_json("carol", FITTED_AT))
    doc.update(changes)
    return doc


def test_a_twin_file_is_read_back_as_fitted() -> None:
    twin = parse_twin(calibration().to_json("carol", FITTED_AT))
    assert (twin.robot, twin.fitted_by, twin.runs) == ("k1", "carol", ("dance",))
    assert (twin.drive.scale_left, twin.drive.wheel_base_mm, twin.drive.latency_s) == (
        0.96, 55.0, 0.0,
    )  # fmt: skip
    assert twin.fitted == ("scale_left", "scale_right", "wheel_base_mm")  # latency refused
    assert twin.model() == f"k1's twin fitted {DAY} by carol"


@pytest.mark.parametrize(
    ("doc", "said"),
    [
        (document(format="wart-map"), 'format: must be "wart-twin"'),
        (document(robot="../etc"), "robot: a robot's name"),
        (document(fitted_by=""), "fitted_by: who fitted it"),
        (document(fitted_at=time.time() + 10 * 86400), "fitted_at: when it was fitted"),
        (document(runs=[]), "runs: the names of 1 to 100"),
        (document(colour="red"), "colour: unknown field"),
    ],
)
def test_a_bad_twin_file_is_refused_with_its_field(doc: dict[str, Any], said: str) -> None:
    with pytest.raises(TwinFileError, match=said.replace("(", r"\(").replace(".", r"\.")):
        parse_twin(json.dumps(doc))


def test_every_problem_of_a_twin_file_is_named_together() -> None:
    doc = document()
    doc["parameters"]["scale_left"]["value"] = 7.0  # no Khepera slips so
    doc["parameters"]["wheel_base_mm"]["value"] = float("nan")  # JSON's NaN: not a number
    doc["parameters"]["ir2_gain"]["sigma"] = -1
    doc["parameters"]["warp"] = {"value": 1.0}
    del doc["parameters"]["latency_s"]
    with pytest.raises(TwinFileError) as caught:
        parse_twin(json.dumps(doc), "k1.json")
    said = str(caught.value)
    for part in (
        "k1.json: parameters.scale_left.value: a number from 0.5 to 1.5, got 7.0",
        "parameters.wheel_base_mm.value: a number from 30 to 80, got nan",
        "parameters.ir2_gain.sigma: null or a number at least 0, got -1",
        "parameters.warp: unknown parameter",
        "parameters.latency_s: required",
    ):
        assert part in said, said
    for junk in (b"\xff\xfe", b"[1, 2]", b"{", b" " * (64 * 1024 + 1)):
        with pytest.raises(TwinFileError):
            parse_twin(junk)


def lab_database(tmp_path: Path) -> Path:
    """The lab's database as the registry makes it at its first start (a file, WAL)."""
    db = tmp_path / "registry.db"
    LabDatabase(db).close()
    return db


def test_the_lab_keeps_every_version_and_the_newest_is_in_force(tmp_path: Path) -> None:
    db = lab_database(tmp_path)
    store = TwinStore.open(db)
    assert store.current("lab", "k1") is None
    first = parse_twin(calibration(scale_left=0.96).to_json("carol", FITTED_AT))
    second = parse_twin(calibration(scale_left=0.95).to_json("dave", FITTED_AT + 86400))
    assert store.save("lab", first, "carol", now=FITTED_AT) == 1
    assert store.save("lab", second, "admin", now=FITTED_AT + 86400) == 2
    store.save("lab", parse_twin(calibration("k2").to_json("carol", FITTED_AT)), "carol")
    store.close()
    store = TwinStore.open(db)  # kept on disk, read by another process's connection
    current = store.current("lab", "k1")
    assert current is not None and current.version == 2 and current.arena == "lab"
    assert current.twin.drive.scale_left == 0.95 and current.saved_by == "admin"
    assert [v.twin.fitted_by for v in store.versions("lab", "k1")] == ["carol", "dave"]
    assert store.robots() == [("lab", "k1", 2), ("lab", "k2", 1)]
    assert (store.count("lab", "k1"), store.count("lab", "k9")) == (2, 0)
    first_line = store.versions("lab", "k1")[0].line()
    assert f"v1: fitted {DAY} by carol from dance; saved {DAY}" in first_line
    # A row written into the database by hand is checked as a file from a user is.
    with sqlite3.connect(db) as raw:
        raw.execute("UPDATE twins SET document = '{\"format\": 1}' WHERE robot = 'k2'")
    with pytest.raises(DbError, match="k2's twin of arena lab v1 in the lab's database"):
        store.current("lab", "k2")
    store.close()


def test_two_arenas_k1_are_two_robots_and_old_rows_are_kept_for_any_arena(
    tmp_path: Path,
) -> None:
    db = lab_database(tmp_path)
    # A database from before twins were kept per arena: rows keyed by robot alone.
    with sqlite3.connect(db) as raw:
        raw.execute(
            "CREATE TABLE twins (robot TEXT NOT NULL, version INTEGER NOT NULL, saved_by TEXT "
            "NOT NULL, saved_at REAL NOT NULL, fitted_by TEXT NOT NULL, fitted_at REAL NOT "
            "NULL, document TEXT NOT NULL, PRIMARY KEY (robot, version))"
        )
        old = calibration(scale_left=0.97).to_json("carol", FITTED_AT)
        raw.execute(
            "INSERT INTO twins VALUES ('k1', 1, 'carol', ?, 'carol', ?, ?)",
            (FITTED_AT, FITTED_AT, old),
        )
    store = TwinStore.open(db)
    kept = store.current("east", "k1")  # the old twin, in force in any arena without its own
    assert kept is not None and kept.arena == "" and kept.twin.drive.scale_left == 0.97
    assert store.robots() == [("", "k1", 1)]
    east = parse_twin(calibration(scale_left=0.95).to_json("ida", FITTED_AT))
    west = parse_twin(calibration(scale_left=1.04).to_json("joe", FITTED_AT))
    assert store.save("east", east, "ida") == 1 and store.save("west", west, "joe") == 1
    got = {a: store.current(a, "k1") for a in ("east", "west", "north")}
    assert {a: (t.arena, t.twin.fitted_by) for a, t in got.items() if t} == {
        "east": ("east", "ida"), "west": ("west", "joe"), "north": ("", "carol"),
    }  # fmt: skip
    assert store.robots() == [("", "k1", 1), ("east", "k1", 1), ("west", "k1", 1)]
    store.close()


def test_a_robot_file_refuses_an_impossible_drive() -> None:
    text = (Path(registry.__file__).parent / "shipped" / "khepera.toml").read_text()
    components = registry.build().components
    for extra, said in (
        ("latency_s = 2.0", "components.drive.latency_s: must be at most 0.5 s, got 2.0"),
        ("wheel_scale = [0.9]", "components.drive.wheel_scale: must be two numbers [left, right]"),
        ("wheel_scale = [0.9, 0.2]", "components.drive.wheel_scale: item 1: must be at least 0.5"),
    ):
        bad = text.replace("wheel_base_mm = 53.0", f"wheel_base_mm = 53.0\n{extra}")
        with pytest.raises(RobotFileError, match=re.escape(said)):
            parse(bad, "k.toml", components)
