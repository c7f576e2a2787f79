"""Argument parsing shared by every ``wart`` subcommand."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from common.auth import parse_public_key
from common.log import setup_logging
from common.zconfig import ConfigError, NetworkOptions, add_network_arguments, options_from_args


def parser(
    prog: str, description: str, *, network: bool = True, default_mode: str = "client"
) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--log-level",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        type=str.upper,
        help="how much to log (default INFO, or WART_LOG_LEVEL)",
    )
    if network:
        add_network_arguments(p, default_mode=default_mode)
    return p


def parse(
    p: argparse.ArgumentParser, argv: Sequence[str] | None
) -> tuple[argparse.Namespace, NetworkOptions | None]:
    """Parse, set up logging, resolve network options; a bad option exits with a clear message."""
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    if not hasattr(args, "no_multicast"):
        return args, None
    try:
        return args, options_from_args(args)
    except ConfigError as exc:
        p.error(str(exc))
        raise  # unreachable: error() exits


def parse_networked(
    p: argparse.ArgumentParser, argv: Sequence[str] | None
) -> tuple[argparse.Namespace, NetworkOptions]:
    """:func:`parse` for a command that joins a lab: its parser has the network options
    (``parser(network=True)``, the default), so they are always there."""
    args, options = parse(p, argv)
    if options is None:
        raise TypeError(f"{p.prog}: a parser without network options (made with network=False)")
    return args, options


def registry_key(p: argparse.ArgumentParser, options: NetworkOptions) -> bytes | None:
    """The registry's public key from --registry-key (None without it); a bad one exits."""
    if not options.registry_key:
        return None
    try:
        return parse_public_key(options.registry_key)
    except ValueError as exc:
        p.error(f"--registry-key: {exc}")
        raise  # unreachable: error() exits


def fail(message: str, code: int = 2) -> int:
    print(f"error: {message}", file=sys.stderr)
    return code


IDENTITY_HELP = "the service account's Ed25519 key file"


def add_account_arguments(
    p: argparse.ArgumentParser, name: str, name_help: str, user_help: str
) -> None:
    """--name (default ``name``), --user and --identity: a service that logs in with a
    service account."""
    p.add_argument("--name", default=name, help=name_help)
    p.add_argument("--user", required=True, help=user_help)
    p.add_argument("--identity", type=Path, required=True, help=IDENTITY_HELP)


def add_context_arguments(p: argparse.ArgumentParser, what: str, example: str) -> None:
    """The options every context process shares (chat rooms, agent contexts)."""
    p.add_argument("--name", required=True, help=f"the {what}'s id (one key chunk, e.g. {example})")
    p.add_argument("--title", default="", help=f"the {what}'s title shown to users")
    p.add_argument("--user", required=True, help=f"the {what}'s service account")
    p.add_argument("--identity", type=Path, required=True, help=IDENTITY_HELP)
    p.add_argument("--owner", help=f"the user who owns the {what} (default: the service account)")
    p.add_argument(
        "--data-dir",
        type=Path,
        help=f"where the {what} keeps its chat history (and an agent context its queues)",
    )
    p.add_argument("--history", type=int, default=200, help="lines of history kept (default 200)")
    p.add_argument(
        "--restricted",
        action="store_true",
        help=f"only users granted rights in this {what} (scope ctx/NAME) may act",
    )
