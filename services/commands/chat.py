"""``wart chat ROOM``: chat in a room from a terminal (plain lines; fine under tmux).

Log in with --user and the password from --password-file, WART_PASSWORD or a
prompt. Type a line and Enter to say it. Commands:

  /who               members of the room        /dir           the lab's directory
  /msg USER TEXT     a private message          /kick USER [REASON]
  /quit              leave (or Ctrl-D)
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Sequence

from common import cli, keys
from common.client.lab_client import LabClient
from common.client.private_mail import PrivateText
from common.lab_errors import LabError
from common.messages import ChatLine, KickNotice, RoomEvent
from common.service import close_session
from services.commands.terminal import connect, password_from, say


def show_line(line: ChatLine) -> None:
    say(f"[{time.strftime('%H:%M', time.localtime(line.at))}] <{line.sender}> {line.text}")


def on_event(event: RoomEvent) -> None:
    if event.line is not None:
        show_line(event.line)
    if event.status is not None:
        s = event.status
        extra = f" by {s.by}" if s.by else ""
        why = f" ({s.reason})" if s.reason else ""
        say(f"* {s.user} {s.status}{extra}{why}; here: {', '.join(event.members)}")


def main(argv: Sequence[str] | None = None, prog: str = "wart chat") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("room", help="the room to join, e.g. lobby")
    p.add_argument("--user", required=True)
    p.add_argument("--password-file", help="read the password from this file")
    args, options = cli.parse_networked(p, argv)
    if not options.registry_key:
        return cli.fail(
            "--registry-key (or WART_REGISTRY_KEY) is required: the key wart up printed"
        )
    try:
        keys.check_ident("room", args.room)
        zsession = connect(options)
    except (ValueError, LabError) as exc:
        return cli.fail(str(exc))
    done = threading.Event()
    try:
        with LabClient(zsession, options.realm, options.registry_key) as client:
            client.on_private = lambda m: say(_private(m))

            def on_kicked(notice: KickNotice) -> None:
                say(_kicked(notice))
                done.set()

            client.on_kicked = on_kicked
            client.login(args.user, password_from(args))
            say(f"logged in to {client.server_name} as {args.user}")
            for message in client.pending:
                say(_private(message))
            room = client.join(args.room, on_event)
            say(f"room {room.title} (owner {room.owner}); here: {', '.join(room.members)}")
            for line in room.history:
                show_line(line)
            return _loop(client, args.room, done)
    except LabError as exc:
        return cli.fail(str(exc), 1)
    finally:
        close_session(zsession)


def _private(message: PrivateText) -> str:
    kept = " (while you were away)" if message.kept else ""
    return f"[private from {message.sender}{kept}] {message.text}"


def _kicked(notice: KickNotice) -> str:
    return f"*** you were kicked from the server by {notice.by}: {notice.reason}"


def _loop(client: LabClient, room: str, done: threading.Event) -> int:
    for raw in sys.stdin:
        if done.is_set():
            return 1
        text = raw.rstrip("\n")
        if not text.strip():
            continue
        try:
            if text in ("/quit", "/exit"):
                break
            if text == "/who":
                handle = client.room(room)
                say("here: " + ", ".join(handle.members if handle else []))
            elif text == "/dir":
                d = client.directory()
                say(f"{d.server_name}: online {', '.join(d.users)}")
                for c in d.contexts:
                    say(f"  {c.ctx} ({c.kind}, owner {c.owner}, {len(c.members)} here)")
            elif text.startswith("/msg "):
                _, user, body = ([*text.split(" ", 2), ""])[:3]
                live = client.send_private(user, body)
                say(f"(to {user}{'' if live else ', kept until they log in'}) {body}")
            elif text.startswith("/kick "):
                _, user, reason = ([*text.split(" ", 2), ""])[:3]
                client.kick(room, user, reason)
            else:
                client.say(room, text)
        except LabError as exc:
            say(f"! {exc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
