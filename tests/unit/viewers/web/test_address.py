"""The address bar's parser, saved connections and completion (pure, no browser)."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.client.lab_address import (
    AddressError,
    LabAddress,
    SavedConnections,
    complete,
    parse_address,
)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "wart://ana@lab.example.org:7448/physics/arena",
            LabAddress("lab.example.org", 7448, "physics", "ana", "arena"),
        ),
        ("lab.example.org", LabAddress("lab.example.org")),
        ("  LAB.Example.org.  ", LabAddress("lab.example.org")),
        ("ana@10.0.0.5", LabAddress("10.0.0.5", user="ana")),
        ("10.0.0.5:7448/physics", LabAddress("10.0.0.5", 7448, "physics")),
        ("WART://localhost/lab/", LabAddress("localhost", realm="lab")),
        ("[fe80::1]:7447/lab", LabAddress("fe80::1", 7447, "lab")),
        ("wart://[::1]/lab/chat1", LabAddress("::1", realm="lab", context="chat1")),
    ],
)
def test_parses(text: str, expected: LabAddress) -> None:
    assert parse_address(text) == expected


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("", "type an address"),
        ("http://lab.example.org", "only wart://"),
        ("lab example", "no spaces"),
        ("lab.example.org:", "port number"),
        ("lab.example.org:99999", "1 to 65535"),
        ("lab.example.org:http", "1 to 65535"),
        ("bad host!", "no spaces"),
        ("under_score.org", "not a host name"),
        ("-lab.org", "not a host name"),
        ("@lab.org", "user name"),
        ("a b@lab", "no spaces"),
        ("lab.org/re*alm", "realm"),
        ("lab.org/lab/ctx/more", "ends at /realm/context"),
        ("[fe80::1", "closing"),
        ("[nothex]:7447", "not an IPv6"),
        ("x" * 400, "too long"),
        ("/lab", "no host"),
    ],
)
def test_refuses_in_plain_words(text: str, says: str) -> None:
    with pytest.raises(AddressError, match=says):
        parse_address(text)


def test_defaults_come_from_the_viewer() -> None:
    address = parse_address("lab.org", default_port=7500, default_realm="physics")
    assert (address.port, address.realm) == (7500, "physics")


@pytest.mark.parametrize(
    "address",
    [
        LabAddress("lab.example.org", 7448, "physics", "ana", "arena"),
        LabAddress("fe80::1", realm="lab"),
        LabAddress("10.0.0.5"),
    ],
)
def test_url_round_trips(address: LabAddress) -> None:
    assert parse_address(address.url()) == address


def test_endpoint_and_label() -> None:
    assert LabAddress("fe80::1").endpoint == "tcp/[fe80::1]:7447"
    assert LabAddress("lab.org", 7448, "physics").label == "physics@lab.org:7448"
    assert LabAddress("lab.org").label == "lab@lab.org"
    # the same lab whoever logs in and whichever context is opened
    assert LabAddress("Lab.org", user="a").lab_key == LabAddress("lab.org", context="c").lab_key


def test_saved_connections_per_user_and_persisted(tmp_path: Path) -> None:
    path = tmp_path / "viewer" / "connections.json"
    saved = SavedConnections(path)
    one, two = parse_address("ana@lab.org"), parse_address("ana@other.org/physics")
    saved.add_recent("ana", one)
    saved.add_recent("ana", two)
    saved.save("ana", one)
    saved.add_recent("ben", two)
    assert saved.for_user("ana") == [one.url(), two.url()]  # saved first, no duplicates
    reloaded = SavedConnections(path)
    assert reloaded.for_user("ana") == [one.url(), two.url()]
    assert reloaded.for_user("ben") == [two.url()]
    assert reloaded.for_user("carl") == []
    reloaded.forget("ana", one.url())
    assert SavedConnections(path).for_user("ana") == [two.url()]


def test_recent_list_is_bounded(tmp_path: Path) -> None:
    saved = SavedConnections(tmp_path / "c.json")
    for i in range(25):
        saved.add_recent("ana", parse_address(f"host{i}.org"))
    listed = saved.for_user("ana")
    assert len(listed) == 10 and listed[0].startswith("wart://host24.org")


def test_unreadable_file_starts_empty(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_text("{not json")
    assert SavedConnections(path).for_user("ana") == []


def test_completion_prefix_then_substring() -> None:
    urls = ["wart://ana@lab.org:7447/lab", "wart://lab2.org:7447/lab", "wart://x.org:7447/lab"]
    assert complete("lab2", urls) == [urls[1]]
    assert complete("lab", urls)[0] == urls[1]  # host starts with it, before the others
    assert complete("org:7447", urls) == urls  # substring anywhere
    assert complete("wart://ana", urls) == [urls[0]]
    assert complete("", urls) == urls
