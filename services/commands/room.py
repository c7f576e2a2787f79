"""``wart room``: start and stop chat rooms on request (``host`` permission).

    wart room new  --user NAME ROOM [--title "Reading group"] [--on HOST]
    wart room new  --user NAME ROOM --kind race --param world=arena --param laps=2 ...
    wart room stop --user NAME ROOM

``--kind`` starts a context type a plugin gives instead of a chat room
(docs/ROBOTS.md), with ``--param NAME=VALUE`` checked against its schema.

The room is owned by the user who asks (they may kick there) and appears in
the lobby's directory for everyone. Network flags as for ``wart chat`` (a
``wart up`` lab: --registry-key or WART_REGISTRY_KEY), or --lab FILE for a
multi-host lab; see ``wart arena``. The password comes from --password-file,
WART_PASSWORD or a prompt.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from common import cli
from common.client.host_client import host_room, stop_hosted
from common.zconfig import NetworkOptions
from services.commands.arena import add_lab_arguments, lab_login, run_lab_command


def main(argv: Sequence[str] | None = None, prog: str = "wart room") -> int:
    p = cli.parser(prog, __doc__ or "")
    add_lab_arguments(p)
    sub = p.add_subparsers(dest="verb", required=True)
    s_new = sub.add_parser("new", help="start a chat room owned by you")
    s_new.add_argument("--title", default="", help="the title shown to users (default: the name)")
    s_new.add_argument("--on", dest="host", help="this host instead of the least busy")
    s_new.add_argument("--kind", default="chat", help="a plugin's context type (default chat)")
    s_new.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a parameter of --kind's context type (repeat)",
    )
    s_stop = sub.add_parser("stop", help="stop a chat room started on request")
    for s in (s_new, s_stop):
        s.add_argument("room", help="the room's name: letters, digits, _ - .")
        s.add_argument("--user", required=True)
        s.add_argument("--password-file", help="read the password from this file")
    return run_lab_command(p, argv, _run)


def _run(args: argparse.Namespace, options: NetworkOptions) -> int:
    with lab_login(args, options) as client:
        if args.verb == "new":
            params = dict(_pair(text) for text in args.param)
            room = host_room(
                client, args.room, args.title, host=args.host, kind=args.kind, params=params
            )
            what = "chat room" if room.kind == "chat" else room.kind
            print(f"{what} {room.name} ({room.title}) is open on {room.host}")
        else:
            print(stop_hosted(client, args.room, "room"))
    return 0


def _pair(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise ValueError(f"--param {text!r}: write NAME=VALUE")
    return name, value


if __name__ == "__main__":
    sys.exit(main())
