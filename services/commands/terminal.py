"""What the terminal commands share: one lock for printing, the password prompt, connecting
and logging in."""

from __future__ import annotations

import argparse
import getpass
import os
import threading
from collections.abc import Callable
from pathlib import Path

import zenoh

from common import cli
from common.client.lab_client import LabClient
from common.lab_errors import LabError, RegistryUnreachable
from common.service import close_session, open_session
from common.zconfig import NetworkOptions

_print_lock = threading.Lock()


def say(text: str) -> None:
    """Print a whole line even when a receiving thread prints at the same time."""
    with _print_lock:
        print(text, flush=True)


def password_from(args: argparse.Namespace) -> str:
    """--password-file, else WART_PASSWORD, else ask on the terminal."""
    if args.password_file:
        return Path(args.password_file).read_text().rstrip("\n")
    return os.environ.get("WART_PASSWORD") or getpass.getpass(f"password for {args.user}: ")


def connect(options: NetworkOptions, *, wait: float = 10.0) -> zenoh.Session:
    """A Zenoh session for a terminal client, with a clear error when no router answers."""
    try:
        return open_session(options, wait=wait)
    except ConnectionError as exc:
        raise RegistryUnreachable(str(exc)) from None


def run_logged_in(
    args: argparse.Namespace, options: NetworkOptions, body: Callable[[LabClient], int]
) -> int:
    """Connect, log in as --user and run ``body``; errors become clear messages."""
    if not options.registry_key:
        return cli.fail(
            "--registry-key (or WART_REGISTRY_KEY) is required: the key wart up printed"
        )
    try:
        zsession = connect(options)
    except LabError as exc:
        return cli.fail(str(exc))
    try:
        with LabClient(zsession, options.realm, options.registry_key) as client:
            client.login(args.user, password_from(args))
            return body(client)
    except LabError as exc:
        return cli.fail(str(exc), 1)
    finally:
        close_session(zsession)
