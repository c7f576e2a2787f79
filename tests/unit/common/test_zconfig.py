"""Network options: file < environment < flag, and clear errors for bad values."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from common.zconfig import (
    DEFAULT_ROUTER,
    ConfigError,
    add_network_arguments,
    options_from_args,
    zenoh_config,
)


def parse(argv: list[str], env: dict[str, str] | None = None):
    p = argparse.ArgumentParser()
    add_network_arguments(p)
    return options_from_args(p.parse_args(argv), env or {})


def test_defaults_are_a_local_client_without_multicast() -> None:
    options = parse([])
    assert options.mode == "client" and options.realm == "lab"
    assert options.effective_connect == (DEFAULT_ROUTER,)
    assert options.multicast_scouting is False


def test_environment_fills_in_and_flags_win() -> None:
    env = {
        "WART_REALM": "envlab",
        "WART_CONNECT": "tcp/10.0.0.1:7447,tcp/10.0.0.2:7447",
        "WART_MODE": "peer",
    }
    from_env = parse([], env)
    assert from_env.realm == "envlab" and from_env.mode == "peer"
    assert from_env.connect == ("tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447")
    flagged = parse(["--realm", "flaglab", "--connect", "tcp/127.0.0.1:9000"], env)
    assert flagged.realm == "flaglab" and flagged.connect == ("tcp/127.0.0.1:9000",)


def test_flags_override_the_config_file(tmp_path: Path) -> None:
    conf_file = tmp_path / "zenoh.json5"
    conf_file.write_text(json.dumps({"mode": "peer", "connect": {"endpoints": ["tcp/1.2.3.4:1"]}}))
    options = parse(["--config", str(conf_file), "--connect", "tcp/127.0.0.1:7000"])
    conf = json.loads(zenoh_config(options).get_json("connect/endpoints"))
    assert conf == ["tcp/127.0.0.1:7000"]


def test_multicast_can_be_turned_on_by_flag_only_explicitly() -> None:
    assert parse(["--multicast-scouting"]).multicast_scouting is True
    assert parse([], {"WART_NO_MULTICAST": "0"}).multicast_scouting is True
    assert (
        parse(["--no-multicast-scouting"], {"WART_NO_MULTICAST": "0"}).multicast_scouting is False
    )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--realm", "a/b"], "not a valid name"),
        (["--connect", "10.0.0.1:7447"], "not a Zenoh endpoint"),
        (["--config", "/nonexistent/z.json5"], "does not exist"),
    ],
)
def test_bad_options_are_explained(argv: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse(argv)


def test_options_survive_the_trip_to_a_child_process() -> None:
    options = parse(["--realm", "x1", "--connect", "tcp/127.0.0.1:7001", "--registry-key", "ab"])
    assert parse(options.as_args()) == options
