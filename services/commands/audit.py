"""``wart audit``: the lab's audit trail, listed, filtered and exported (admins).

Every privileged action and every refusal of one, kept by the registry in its
database: kicks, bans, grants, accounts, emergency stops and releases,
slot-length changes (docs/SECURITY.md "Audit trail"). Newest first.

    wart audit --user admin --registry-key KEY                 # the last 50, as a table
    wart audit --user admin --actor ida --action estop --since 2026-11-26T10:00
    wart audit --user admin --format csv --out term.csv --limit 5000

Times are UTC (ISO 8601, or seconds since the epoch); the password comes from
--password-file, WART_PASSWORD or a prompt.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

from common import cli, keys
from common.messages import MAX_AUDIT_PAGE, AuditEntry, AuditQuery
from common.zconfig import NetworkOptions
from services.commands.arena import add_lab_arguments, lab_login, run_lab_command

COLUMNS = ("id", "at", "actor", "action", "target", "outcome", "detail", "source", "reporter")


def parse_time(text: str, flag: str) -> float:
    """A UTC time as typed: ISO 8601 (date, or date and time) or epoch seconds."""
    try:
        return float(text)
    except ValueError:
        pass
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise ValueError(
            f"{flag}: {text!r} is not a time (2026-11-26T10:42, 2026-11-26, or epoch seconds)"
        ) from None
    return (when if when.tzinfo else when.replace(tzinfo=UTC)).timestamp()


def iso(at: float) -> str:
    return datetime.fromtimestamp(at, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def rows(entries: Sequence[AuditEntry]) -> list[dict[str, object]]:
    return [{c: iso(e.at) if c == "at" else getattr(e, c) for c in COLUMNS} for e in entries]


def render(entries: Sequence[AuditEntry], fmt: str) -> str:
    """The entries as a table (for people), CSV or JSON (for other tools)."""
    if fmt == "json":
        return json.dumps(rows(entries), indent=1) + "\n"
    if fmt == "csv":
        out = io.StringIO()
        writer = csv.DictWriter(out, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows(entries))
        return out.getvalue()
    if not entries:
        return "no audit lines match\n"
    lines = []
    for e in entries:
        detail = f"  ({e.detail})" if e.detail else ""
        lines.append(
            f"{iso(e.at)}  {e.actor:<12} {e.action:<13} {e.target:<20} {e.outcome:<7}"
            f" from {e.source or '?'} [{e.reporter}]{detail}"
        )
    return "\n".join(lines) + "\n"


def query_from(args: argparse.Namespace) -> AuditQuery:
    if not 1 <= args.limit <= MAX_AUDIT_PAGE:
        raise ValueError(f"--limit must be between 1 and {MAX_AUDIT_PAGE}")
    if args.actor:
        keys.check_ident("--actor", args.actor)
    if args.action and not args.action.replace("_", "").isalnum():
        raise ValueError(f"--action {args.action!r}: a short name such as estop, kick, grant")
    return AuditQuery(
        actor=args.actor or "",
        action=args.action or "",
        target=(args.target or "")[:200],
        outcome=args.outcome or "",
        since=parse_time(args.since, "--since") if args.since else None,
        until=parse_time(args.until, "--until") if args.until else None,
        limit=args.limit,
    )


def main(argv: Sequence[str] | None = None, prog: str = "wart audit") -> int:
    p = cli.parser(prog, __doc__ or "")
    add_lab_arguments(p)
    p.add_argument("--user", required=True, help="an account with the admin permission")
    p.add_argument("--password-file", help="read the password from this file")
    p.add_argument("--actor", help="only what this user did or was refused")
    p.add_argument("--action", help="only this action (kick, ban, grant, estop, settings...)")
    p.add_argument("--target", help="only targets containing this text (a user, ctx/arena)")
    p.add_argument("--outcome", choices=("ok", "refused"))
    p.add_argument("--since", help="from this UTC time (2026-11-26T10:00)")
    p.add_argument("--until", help="up to this UTC time")
    p.add_argument("--limit", type=int, default=50, help=f"at most this many (≤ {MAX_AUDIT_PAGE})")
    p.add_argument("--format", choices=("table", "csv", "json"), default="table")
    p.add_argument("--out", type=Path, help="write to this file instead of the terminal")
    return run_lab_command(p, argv, _run)


def _run(args: argparse.Namespace, options: NetworkOptions) -> int:
    query = query_from(args)  # refused before any network
    with lab_login(args, options) as client:
        entries, more = client.audit_trail(query)
    text = render(entries, args.format)
    if args.out is not None:
        args.out.write_text(text)
        print(f"{len(entries)} audit lines written to {args.out}")
    else:
        sys.stdout.write(text)
    if more:
        print("(older lines match too: raise --limit or narrow with --since)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
