"""One Zenoh configuration helper for every program.

Every ``wart`` command takes the same network flags::

    --realm NAME  --mode {client,peer,router}  --connect ENDPOINT ...
    --listen ENDPOINT ...  --config FILE  --no-multicast-scouting
    --registry-key HEX

Precedence, lowest first: the Zenoh config file (``--config`` or
``WART_ZENOH_CONFIG``), then environment variables (``WART_REALM``,
``WART_MODE``, ``WART_CONNECT``, ``WART_LISTEN`` with comma-separated endpoints,
``WART_NO_MULTICAST=1``, ``WART_REGISTRY_KEY``), then explicit flags. An
environment variable never overrides a flag given on the command line.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import zenoh

from common.keys import check_ident

DEFAULT_REALM = "lab"
DEFAULT_PORT = 7447
DEFAULT_ROUTER = f"tcp/127.0.0.1:{DEFAULT_PORT}"
MODES = ("client", "peer", "router")


class ConfigError(ValueError):
    """A network option is wrong; the message says which and why."""


@dataclass(frozen=True)
class NetworkOptions:
    realm: str = DEFAULT_REALM
    mode: str = "client"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    config_file: Path | None = None
    multicast_scouting: bool = False
    registry_key: str | None = None  # hex Ed25519 verify key, pinned
    extra: Mapping[str, object] = field(default_factory=dict)  # raw JSON5 inserts

    def with_(self, **changes: object) -> NetworkOptions:
        return replace(self, **changes)  # type: ignore[arg-type]

    @property
    def effective_connect(self) -> tuple[str, ...]:
        """Where a client connects when nothing was said: the local router."""
        if self.connect or self.mode == "router":
            return self.connect
        return (DEFAULT_ROUTER,)

    def as_args(self) -> list[str]:
        """These options as command-line flags, to hand to a child process."""
        args = ["--realm", self.realm, "--mode", self.mode]
        for endpoint in self.connect:
            args += ["--connect", endpoint]
        for endpoint in self.listen:
            args += ["--listen", endpoint]
        if self.config_file:
            args += ["--config", str(self.config_file)]
        if not self.multicast_scouting:
            args.append("--no-multicast-scouting")
        if self.registry_key:
            args += ["--registry-key", self.registry_key]
        return args


def add_network_arguments(parser: argparse.ArgumentParser, *, default_mode: str = "client") -> None:
    group = parser.add_argument_group("network (Zenoh)")
    group.add_argument(
        "--realm",
        help=f"the lab's name: its key space is wart/<realm>/** (default {DEFAULT_REALM})",
    )
    group.add_argument("--mode", choices=MODES, help=f"Zenoh session mode (default {default_mode})")
    group.add_argument(
        "--connect",
        "-e",
        action="append",
        metavar="ENDPOINT",
        help=f"router to connect to, e.g. tcp/10.0.0.5:7447 (repeatable; default {DEFAULT_ROUTER})",
    )
    group.add_argument(
        "--listen",
        "-l",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)",
    )
    group.add_argument("--config", type=Path, metavar="FILE", help="a Zenoh JSON5 config file")
    group.add_argument(
        "--no-multicast-scouting",
        dest="no_multicast",
        action="store_true",
        default=None,
        help="do not discover peers by multicast (the default; kept for zenoh-style scripts)",
    )
    group.add_argument(
        "--multicast-scouting",
        dest="no_multicast",
        action="store_false",
        help="discover routers and peers on the LAN by multicast",
    )
    group.add_argument(
        "--registry-key",
        metavar="HEX",
        help="the registry's public key to trust (printed by the registry at first start)",
    )
    parser.set_defaults(_default_mode=default_mode)


def _split(value: str) -> tuple[str, ...]:
    return tuple(part.strip() for part in value.split(",") if part.strip())


def options_from_args(
    args: argparse.Namespace, env: Mapping[str, str] | None = None
) -> NetworkOptions:
    """Resolve flags, environment and config file into NetworkOptions."""
    env = os.environ if env is None else env
    default_mode = getattr(args, "_default_mode", "client")

    config_file = args.config or (
        Path(env["WART_ZENOH_CONFIG"]) if env.get("WART_ZENOH_CONFIG") else None
    )
    if config_file is not None and not config_file.is_file():
        raise ConfigError(f"Zenoh config file {config_file} does not exist")

    realm = args.realm or env.get("WART_REALM") or DEFAULT_REALM
    try:
        check_ident("realm", realm)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None

    mode = args.mode or env.get("WART_MODE") or default_mode
    if mode not in MODES:
        raise ConfigError(f"WART_MODE={mode!r} is not one of {', '.join(MODES)}")

    connect = tuple(args.connect) if args.connect else _split(env.get("WART_CONNECT", ""))
    listen = tuple(args.listen) if args.listen else _split(env.get("WART_LISTEN", ""))
    for endpoint in connect + listen:
        _check_endpoint(endpoint)

    if args.no_multicast is not None:
        multicast = not args.no_multicast
    else:
        multicast = env.get("WART_NO_MULTICAST", "1") not in ("1", "true", "yes")

    registry_key = args.registry_key or env.get("WART_REGISTRY_KEY") or None
    return NetworkOptions(
        realm=realm,
        mode=mode,
        connect=connect,
        listen=listen,
        config_file=config_file,
        multicast_scouting=multicast,
        registry_key=registry_key,
    )


def _check_endpoint(endpoint: str) -> None:
    proto, sep, rest = endpoint.partition("/")
    if not sep or not rest or proto not in ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream"):
        raise ConfigError(
            f"{endpoint!r} is not a Zenoh endpoint: write PROTOCOL/ADDRESS, e.g. tcp/10.0.0.5:7447"
        )


def zenoh_config(options: NetworkOptions) -> zenoh.Config:
    """A zenoh.Config from the options; flags are inserted over the file's values."""
    conf = (
        zenoh.Config.from_file(str(options.config_file)) if options.config_file else zenoh.Config()
    )

    def put(key: str, value: object) -> None:
        conf.insert_json5(key, json.dumps(value))

    put("mode", options.mode)
    if options.effective_connect:
        put("connect/endpoints", list(options.effective_connect))
    if options.listen:
        put("listen/endpoints", list(options.listen))
    put("scouting/multicast/enabled", options.multicast_scouting)
    # Without this, opening a session waits ~500 ms for scouting replies.
    put("scouting/delay", 0)
    for key, value in options.extra.items():
        put(key, value)
    return conf
