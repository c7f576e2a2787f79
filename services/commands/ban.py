"""``wart ban``: keep an account out of the lab for a while, or for good (admins).

A ban revokes the account's live sessions at once (like a kick) and refuses
its logins, telling the user the reason and the end; lifting it is logged in
the audit trail like the ban itself (``wart audit``).

    wart ban --user admin bob --reason "spamming the lobby" --for 1d
    wart ban --user admin bob --reason "cheating" --until 2026-12-20T00:00
    wart ban --user admin bob --reason "for good"                 # until lifted
    wart ban --user admin --lift bob --reason "apologised"
    wart ban --user admin --list

The password comes from --password-file, WART_PASSWORD or a prompt.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections.abc import Sequence

from common import cli, keys
from common.zconfig import NetworkOptions
from services.commands.arena import add_lab_arguments, lab_login, run_lab_command
from services.commands.audit import iso, parse_time

_UNITS = {"m": 60.0, "h": 3600.0, "d": 86400.0, "w": 7 * 86400.0}


def parse_duration(text: str) -> float:
    """``30m``, ``12h``, ``1d``, ``2w``: seconds."""
    match = re.fullmatch(r"(\d+(?:\.\d+)?)([mhdw])", text.strip())
    if match is None or float(match.group(1)) <= 0:
        raise ValueError(f"--for {text!r}: a positive number and a unit: 30m, 12h, 1d or 2w")
    return float(match.group(1)) * _UNITS[match.group(2)]


def main(argv: Sequence[str] | None = None, prog: str = "wart ban") -> int:
    p = cli.parser(prog, __doc__ or "")
    add_lab_arguments(p)
    p.add_argument("--user", required=True, help="an account with the admin permission")
    p.add_argument("--password-file", help="read the password from this file")
    p.add_argument("account", nargs="?", help="the account to ban (or, with --lift, to let in)")
    p.add_argument("--reason", default="", help="shown to the banned user at each login")
    end = p.add_mutually_exclusive_group()
    end.add_argument("--for", dest="duration", help="how long: 30m, 12h, 1d, 2w")
    end.add_argument("--until", help="until this UTC time (2026-12-20T00:00)")
    verb = p.add_mutually_exclusive_group()
    verb.add_argument("--lift", action="store_true", help="lift the account's ban")
    verb.add_argument("--list", action="store_true", help="the bans in force")
    return run_lab_command(p, argv, _run)


def _until(args: argparse.Namespace) -> float | None:
    if args.duration:
        return time.time() + parse_duration(args.duration)
    if args.until:
        return parse_time(args.until, "--until")
    return None


def _run(args: argparse.Namespace, options: NetworkOptions) -> int:
    # Everything typed is checked before the network is touched.
    if not args.list:
        if not args.account:
            raise ValueError("name the account (or --list the bans in force)")
        keys.check_ident("account", args.account)
    if len(args.reason) > 200:
        raise ValueError("--reason: at most 200 characters")
    if not (args.list or args.lift) and not args.reason.strip():
        raise ValueError("--reason is required: the banned user is told it at each login")
    until = None if args.list or args.lift else _until(args)
    with lab_login(args, options) as client:
        if args.list:
            banned = [u for u in client.list_users() if u.ban is not None]
            for u in banned:
                assert u.ban is not None
                end = iso(u.ban.until) if u.ban.until else "until lifted"
                print(f"{u.name:<16} {end:<22} by {u.ban.by}: {u.ban.reason}")
            if not banned:
                print("nobody is banned")
        elif args.lift:
            print(client.lift_ban(args.account, args.reason.strip()))
        else:
            print(client.ban(args.account, args.reason.strip(), until))
    return 0


if __name__ == "__main__":
    sys.exit(main())
