"""``wart context KIND ...``: run a context process, a chat room or an agent context.

A chat room (chat_room.py) holds members, history and private rate limits; an
agent context (agent_context.py) is a chat room plus a queue per robot of one
world (agent_queue.py), and grants each controller its time slot.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import zenoh

from common import cli, keys
from common.client.service_login import ServiceCredentials
from common.messages import MAX_LINE_CHARS
from common.recording.store import RecordingStore
from common.robots import registry
from common.service import run_service
from common.zconfig import NetworkOptions
from services.context import agent_context, chat_room
from services.context.agent_context import AgentContext
from services.context.chat_room import ChatRoom, log
from services.context.recordings import recordings_dir


def _checked_credentials(
    kind: str, args: argparse.Namespace, options: NetworkOptions, *idents: tuple[str, str]
) -> ServiceCredentials:
    """A context's --name (a ``kind`` id), then ``idents`` (what, value) and --owner checked,
    then its service account's credentials (ValueError saying what is wrong)."""
    keys.check_ident(kind, args.name)
    for what, value in idents:
        keys.check_ident(what, value)
    if args.owner:
        keys.check_ident("owner", args.owner)
    return ServiceCredentials.from_options(options.registry_key, args.user, args.identity, kind)


def chat_main(argv: Sequence[str] | None = None, prog: str = "wart context chat") -> int:
    p = cli.parser(prog, chat_room.__doc__ or "")
    cli.add_context_arguments(p, "room", "lobby")
    p.add_argument("--max-line", type=int, default=MAX_LINE_CHARS, help="longest line accepted")
    p.add_argument("--rate", type=float, default=2.0, help="lines per second per user (default 2)")
    p.add_argument("--burst", type=float, default=10.0, help="lines a user may send at once")
    args, options = cli.parse_networked(p, argv)
    try:
        credentials = _checked_credentials("room", args, options)
    except ValueError as exc:
        return cli.fail(str(exc))
    if not (1 <= args.history <= 100_000 and 1 <= args.max_line <= 16_000):
        return cli.fail("--history must be 1..100000 and --max-line 1..16000")
    if args.rate <= 0 or args.burst < 1:
        return cli.fail("--rate must be > 0 and --burst >= 1")

    def build(session: zenoh.Session) -> ChatRoom:
        login = credentials.login(session, options.realm, f"room {args.name}")
        log.info("room %s logged in as %s", args.name, args.user)
        return ChatRoom(
            session,
            options.realm,
            args.name,
            registry_key=credentials.registry_key,
            login=login,
            owner=args.owner or args.user,
            title=args.title,
            data_dir=args.data_dir,
            history_size=args.history,
            max_line=args.max_line,
            burst=args.burst,
            per_second=args.rate,
            restricted=args.restricted,
        )

    return run_service(f"chat room {args.name}", options, build)


def agent_main(argv: Sequence[str] | None = None, prog: str = "wart context agent") -> int:
    p = cli.parser(prog, agent_context.__doc__ or "")
    cli.add_context_arguments(p, "context", "arena")
    p.add_argument("--world", required=True, help="the world whose agents it queues (e.g. arena1)")
    p.add_argument(
        "--runner", default="runner", help="the runner that runs uploads (default runner)"
    )
    p.add_argument(
        "--slot-seconds", type=float, default=60.0, help="each controller's time slot (default 60)"
    )
    p.add_argument(
        "--keep-recordings",
        type=int,
        default=20,
        metavar="N",
        help="recordings kept per user, the oldest removed beyond N (default 20); "
        "0 records nothing",
    )
    p.add_argument(
        "--recordings-dir",
        type=Path,
        default=None,
        help="where slots are recorded (default DATA_DIR/recordings/NAME; "
        "without --data-dir nor this, nothing is recorded)",
    )
    args, options = cli.parse_networked(p, argv)
    try:
        credentials = _checked_credentials(
            "context", args, options, ("world", args.world), ("runner", args.runner)
        )
    except ValueError as exc:
        return cli.fail(str(exc))
    if not 1.0 <= args.slot_seconds <= 3600.0:
        return cli.fail("--slot-seconds must be 1..3600")
    if not 1 <= args.history <= 100_000:
        return cli.fail("--history must be 1..100000")
    if not 0 <= args.keep_recordings <= 100_000:
        return cli.fail("--keep-recordings must be 0..100000")
    where = recordings_dir(args.name, args.data_dir, args.recordings_dir)
    store = None
    if where is not None and args.keep_recordings > 0:
        try:
            store = RecordingStore(where, args.keep_recordings)
        except OSError as exc:
            return cli.fail(f"cannot keep recordings in {where}: {exc.strerror or exc}")

    def build(session: zenoh.Session) -> AgentContext:
        login = credentials.login(session, options.realm, f"context {args.name}")
        return AgentContext(
            session,
            options.realm,
            args.name,
            world=args.world,
            runner=args.runner,
            slot_seconds=args.slot_seconds,
            recordings=store,
            registry_key=credentials.registry_key,
            login=login,
            owner=args.owner or args.user,
            title=args.title,
            data_dir=args.data_dir,
            history_size=args.history,
            restricted=args.restricted,
        )

    return run_service(f"agent context {args.name}", options, build)


KINDS: dict[str, tuple[Callable[..., int], str]] = {
    "chat": (chat_main, "a chat room"),
    "agent": (agent_main, "an agent context: chat + per-robot queues and leases"),
}


def main(argv: Sequence[str] | None = None, prog: str = "wart context") -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in KINDS:  # the lab's own kinds: no plugin is even looked up
        return int(KINDS[args[0]][0](args[1:], prog=f"{prog} {args[0]}") or 0)
    # Context types from plugins (entry points ``wart.contexts``, common/robots/registry.py).
    plugins = registry.default().contexts
    if not args or args[0] in ("-h", "--help"):
        print(f"usage: {prog} KIND [options]   ({prog} KIND --help for each)\n\nkinds:")
        for name, (_, text) in KINDS.items():
            print(f"  {name:<8} {text}")
        for name, kind in plugins.items():
            origin = registry.default().describe_origin("wart.contexts", name)
            print(f"  {name:<8} {getattr(kind, 'doc', '')} (plugin {origin})")
        return 0
    if args[0] in plugins:
        return int(plugins[args[0]].main(args[1:], prog=f"{prog} {args[0]}") or 0)
    known = ", ".join([*KINDS, *plugins])
    print(f"{prog}: unknown context kind {args[0]!r}: one of {known}", file=sys.stderr)
    return 2
