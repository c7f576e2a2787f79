"""The lab file: the example loads; every mistake is refused with the field named."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from services.lab.labfile import LabFileError, load, parse
from tests.conftest import REPO

EXAMPLE = REPO / "deploy" / "lab.example.toml"


def example() -> dict:
    return tomllib.loads(EXAMPLE.read_text())


def test_the_example_loads_with_its_three_hosts_and_a_full_mesh() -> None:
    lab = load(EXAMPLE)
    assert [h.name for h in lab.hosts] == ["A", "B", "C"]
    assert lab.host("C").connect == ("A", "B")
    assert lab.host("B").endpoint == "tls/10.0.0.2:7447"
    assert lab.registry_host().name == "A"
    assert lab.security.pki == EXAMPLE.parent / "pki"
    assert lab.host("A").arenas is False


def edited(change) -> dict:
    data = example()
    change(data)
    return data


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda d: d.pop("realm"), "'realm' is missing"),
        (lambda d: d.update(realm="bad realm"), "realm: 'bad realm' is not a valid name"),
        (lambda d: d.update(lease_ms=10), "lease_ms: 10 is out of range"),
        (lambda d: d.update(colour="red"), "unknown field colour"),
        (lambda d: d["security"].pop("pki"), "security.pki: missing"),
        (lambda d: d["security"].update(acl="yes"), "security.acl: expected true or false"),
        (lambda d: d["limits"].update(max_cpu_percent=150), "limits.max_cpu_percent: 150"),
        (lambda d: d["hosts"][1].update(port=True), "hosts[1].port: expected an integer"),
        (lambda d: d["hosts"][1].update(address="10.0.0.1!"), "hosts[1].address"),
        (lambda d: d["hosts"][2].update(name="A"), "hosts[2].name: host 'A' is listed twice"),
        (lambda d: d["hosts"][1].update(connect=["Z"]), "hosts[1].connect[0]: no host named 'Z'"),
        (lambda d: d["hosts"][1].update(connect=["B"]), "does not connect to itself"),
        (
            lambda d: d["hosts"][1]["services"][0].pop("world"),
            "hosts[1].services[0]: a engine service needs 'world'",
        ),
        (
            lambda d: d["hosts"][1]["services"][0].update(kind="toaster"),
            "hosts[1].services[0].kind: 'toaster' is not a service kind",
        ),
        (
            lambda d: d["hosts"][1]["services"][0].update(seed=-1),
            "hosts[1].services[0].seed: -1 is out of range",
        ),
        (lambda d: d["hosts"][0]["services"].pop(0), "exactly one host runs the registry"),
        (lambda d: d["arena"].update(engine=["engine"]), "arena.engine: command templates"),
        (lambda d: d["arena"].update(agent="yes"), "arena.agent: expected true or false"),
        (lambda d: d["arena"].update(slot_seconds=0), "arena.slot_seconds: 0 is out of range"),
        (lambda d: d.update(hosts=[]), "no [[hosts]]"),
    ],
)
def test_mistakes_name_the_field(change, field: str) -> None:
    with pytest.raises(LabFileError) as info:
        parse(edited(change), EXAMPLE)
    assert field in str(info.value)


def test_a_world_name_is_lab_wide() -> None:
    def twice(d: dict) -> None:
        d["hosts"][2]["services"] = [{"kind": "engine", "world": "arena1", "map": "maze"}]

    with pytest.raises(LabFileError, match="runs on both B and C"):
        parse(edited(twice), EXAMPLE)


def test_unreadable_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(LabFileError, match="cannot read"):
        load(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("realm = \n")
    with pytest.raises(LabFileError, match="not valid TOML"):
        load(bad)
