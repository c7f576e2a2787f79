"""What the terminal commands share: one lock for printing, the password prompt, connecting."""

from __future__ import annotations

import argparse
import getpass
import os
import threading
from pathlib import Path

import zenoh

from common.lab_errors import RegistryUnreachable
from common.service import open_session
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
