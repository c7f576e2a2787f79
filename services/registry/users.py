"""``wart users``: edit accounts and grants in the registry's database.

Works directly on the SQLite file (--db), also while the registry runs (WAL).
Grants and roles take effect at each user's next login.

  wart users --db DB add alice --role student            (asks for the password)
  wart users --db DB add chat-lobby --role service --key-file lobby.key
  wart users --db DB passwd alice
  wart users --db DB grant bob kick --scope ctx/lobby
  wart users --db DB revoke bob kick --scope ctx/lobby
  wart users --db DB remove alice
  wart users --db DB list
  wart users keygen lobby.key                          (an identity key for a service)
  wart users --db DB import class.csv --course robotics-26   (a class from a roster file)
  wart users --db DB courses | course robotics-26
"""

from __future__ import annotations

import argparse
import getpass
import socket
import sys
from collections.abc import Sequence
from pathlib import Path

from common import acl, cli
from common.auth import create_identity_key, load_identity_key, parse_public_key
from services.registry import courses_cli, resume
from services.registry.accounts_db import DbError, RegistryDB
from services.registry.audit_db import Action, TermStore


def read_password(args: argparse.Namespace, prompt: str) -> str:
    """A new password: from --password-file, one line piped on stdin, or a prompt asked twice.

    Never from WART_PASSWORD: that is the password people log in with, and it
    must not silently become someone else's new password.
    """
    if getattr(args, "password_file", None):
        return Path(args.password_file).read_text().rstrip("\n")
    if not sys.stdin.isatty():
        line = sys.stdin.readline()
        if not line.strip():
            raise DbError(
                "bad_request",
                "no password given: pipe one line, use --password-file, or run "
                "this in a terminal to be asked",
            )
        return line.rstrip("\n")
    try:
        first = getpass.getpass(prompt)
        again = getpass.getpass("again: ")
    except EOFError:
        raise DbError("bad_request", "no password given") from None
    if again != first:
        raise DbError("bad_request", "the two passwords differ")
    return first


def main(argv: Sequence[str] | None = None, prog: str = "wart users") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("--db", type=Path, help="the registry database (STATE_DIR/registry.db)")
    sub = p.add_subparsers(dest="command", required=True)
    add = sub.add_parser("add", help="create an account")
    add.add_argument("user")
    add.add_argument("--role", action="append", choices=sorted(acl.DEFAULT_ROLES))
    add.add_argument("--password-file", help="read the password from this file")
    add.add_argument("--no-password", action="store_true", help="key login only")
    add.add_argument("--key-file", type=Path, help="an identity key file: allow key login")
    add.add_argument("--public-key", help="allow key login with this hex public key")
    pw = sub.add_parser("passwd", help="set a user's password")
    pw.add_argument("user")
    pw.add_argument("--password-file")
    rm = sub.add_parser("remove", help="delete an account")
    rm.add_argument("user")
    sub.add_parser("list", help="list accounts and their grants")
    for name, text in (("grant", "give a permission or role:NAME"), ("revoke", "take one away")):
        g = sub.add_parser(name, help=text)
        g.add_argument("user")
        g.add_argument("grant", help="a permission (kick, chat, ...) or role:NAME")
        g.add_argument(
            "--scope", default="", help="ctx/ROOM or agent/CTX/AGENT (default: everywhere)"
        )
    courses_cli.add_parsers(sub)
    kg = sub.add_parser("keygen", help="create an identity key file and print its public key")
    kg.add_argument("file", type=Path)
    args, _ = cli.parse(p, argv)

    if args.command == "keygen":
        try:
            key = create_identity_key(args.file)
        except FileExistsError:
            return cli.fail(f"{args.file} exists; not overwriting an identity key")
        print(bytes(key.verify_key).hex())
        return 0
    if args.db is None:
        return cli.fail("--db is required (the registry's database file)")
    if args.command not in ("add", "import") and not args.db.exists():
        return cli.fail(f"no registry database at {args.db}")
    db = RegistryDB(args.db)
    try:
        run = courses_cli.run if args.command in courses_cli.COMMANDS else _run
        done = run(args, db)
        _audit(args, db)
        return done
    except DbError as exc:
        return cli.fail(exc.message)
    except (ValueError, OSError) as exc:
        return cli.fail(str(exc))
    finally:
        db.close()


# What each change is called in the registry's audit trail (as the registry names its own).
_ACTIONS = {
    "add": "add_user",
    "passwd": "set_password",
    "remove": "remove_user",
    "grant": "grant",
    "revoke": "ungrant",
    "import": "import_roster",
}


def _audit(args: argparse.Namespace, db: RegistryDB) -> None:
    """Changes made on the file bypass the registry: they go into its audit trail too.

    The actor is ``local`` (whoever can write the database file holds every right);
    where it came from is this machine's user and host name.
    """
    action = _ACTIONS.get(args.command)
    if action is None:
        return
    detail = ""
    if args.command in ("grant", "revoke"):
        detail = f"{args.grant} {'in ' + args.scope if args.scope else 'everywhere'}"
    elif args.command == "add":
        detail = "roles " + ", ".join(args.role or ["student"])
    elif args.command == "import":
        if args.dry_run:
            return
        detail = f"roster {args.roster.name}"
    try:
        who = getpass.getuser()
    except (OSError, KeyError):  # no login name in the environment nor the passwd file
        who = "an unknown user"
    where = f"wart users by {who} on {socket.gethostname()}"
    target = f"course/{args.course}" if args.command == "import" else args.user
    TermStore(db).record(Action("local", action, target, "ok", detail, where, "wart-users"))


def _end_sessions(db: RegistryDB, user: str, reason: str, *, kicked: bool) -> int:
    """Every live session and saved login of ``user`` revoked in the file: a running
    registry enforces and publishes them within seconds, a stopped one at its start."""
    resume.revoke_user(db, user, reason)
    return sum(
        db.revoke(s.session_id, reason, kicked=kicked) is not None for s in db.active_sessions(user)
    )


def _run(args: argparse.Namespace, db: RegistryDB) -> int:
    if args.command == "add":
        public_key = None
        if args.key_file:
            public_key = bytes(load_identity_key(args.key_file).verify_key)
        elif args.public_key:
            public_key = parse_public_key(args.public_key)
        password = None
        if not args.no_password and public_key is None:
            password = read_password(args, f"password for {args.user}: ")
        db.add_user(args.user, args.role or ["student"], password=password, public_key=public_key)
        print(f"user {args.user} added")
    elif args.command == "passwd":
        db.set_password(args.user, read_password(args, f"new password for {args.user}: "))
        ended = _end_sessions(db, args.user, "the password was changed", kicked=False)
        print(f"password of {args.user} changed ({ended} sessions ended)")
    elif args.command == "remove":
        ended = _end_sessions(db, args.user, "account removed", kicked=True)
        db.remove_user(args.user)
        print(f"user {args.user} removed ({ended} sessions ended)")
    elif args.command == "grant":
        db.grant(args.user, args.grant, args.scope)
        print(f"granted {args.grant} to {args.user}" + (f" in {args.scope}" if args.scope else ""))
    elif args.command == "revoke":
        db.ungrant(args.user, args.grant, args.scope)
        print(
            f"revoked {args.grant} from {args.user}" + (f" in {args.scope}" if args.scope else "")
        )
    elif args.command == "list":
        for rec in db.users():
            grants = ", ".join(f"{g}@{s}" if s else g for s, g in rec.grants) or "-"
            creds = ",".join(rec.credential_kinds) or "none"
            print(f"{rec.name:<20} {grants}  [{creds}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
