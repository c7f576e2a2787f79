"""A class roster from a CSV file: who is in a course, as what, in which team.

The file is a teacher's export (a spreadsheet, an LMS's class list) and is
checked whole before anything is written: its encoding (UTF-8, a byte-order
mark allowed), its header (``user`` required; ``name``, ``email``, ``role``,
``team`` optional, in any order and case), each row's user name (a lab
identifier), role (``student`` or ``teacher``) and team, and no user twice.
Every problem is reported with its line, up to :data:`MAX_PROBLEMS`.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass

from common.keys import check_ident
from services.registry.accounts_db import RESERVED_NAMES

COLUMNS = ("user", "name", "email", "role", "team")
ROLES = ("student", "teacher")
MAX_BYTES = 1 << 20  # 1 MiB: a class of thousands fits many times over
MAX_ROWS = 5000
MAX_PROBLEMS = 20
MAX_TEXT = 120  # a name, an email or a team


class RosterError(ValueError):
    """The roster cannot be imported; ``problems`` says each reason with its line."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("; ".join(problems))


@dataclass(frozen=True)
class RosterRow:
    line: int
    user: str
    name: str = ""
    email: str = ""
    role: str = "student"
    team: str = ""


def _text(raw: bytes) -> str:
    if len(raw) > MAX_BYTES:
        raise RosterError([f"the file has {len(raw)} bytes: at most {MAX_BYTES} (1 MiB)"])
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise RosterError(
            [f"line {line}: not UTF-8 text (byte {exc.start}); save the file as CSV UTF-8"]
        ) from None


def parse_roster(raw: bytes) -> list[RosterRow]:
    """The rows of a roster file; RosterError with every problem found if it has any."""
    text = _text(raw)
    try:
        dialect = csv.Sniffer().sniff(text[:4096], delimiters=",;\t")
    except csv.Error:
        dialect = csv.excel  # one column, or nothing to tell by: commas
    reader = csv.reader(io.StringIO(text), dialect)
    try:
        header = next(reader)
    except StopIteration:
        raise RosterError(
            ["the file is empty: it needs a header line naming its columns"]
        ) from None
    except csv.Error as exc:
        raise RosterError([f"line 1: {exc}"]) from None
    names = [h.strip().lower() for h in header]
    problems: list[str] = []
    unknown = [h for h in names if h not in COLUMNS]
    if "user" not in names:
        problems.append(f"line 1: no 'user' column (the header has: {', '.join(header)})")
    if unknown:
        problems.append(
            f"line 1: unknown column{'s' * (len(unknown) > 1)} {', '.join(unknown)}; "
            f"the columns are {', '.join(COLUMNS)} (user required)"
        )
    repeated = sorted({h for h in names if names.count(h) > 1})
    if repeated:
        problems.append(f"line 1: column{'s' * (len(repeated) > 1)} {', '.join(repeated)} twice")
    if problems:
        raise RosterError(problems)
    rows: list[RosterRow] = []
    first_line: dict[str, int] = {}
    try:
        for cells in reader:
            line = reader.line_num
            if not any(c.strip() for c in cells):
                continue  # a blank line
            if len(rows) >= MAX_ROWS:
                problems.append(f"line {line}: more than {MAX_ROWS} rows")
                break
            if len(cells) != len(names):
                problems.append(f"line {line}: {len(cells)} cells for {len(names)} columns")
                continue
            row = _row(line, dict(zip(names, (c.strip() for c in cells), strict=True)), problems)
            if row is None:
                continue
            if row.user.lower() in first_line:
                first = first_line[row.user.lower()]
                problems.append(f"line {line}: user {row.user} again (first on line {first})")
                continue
            first_line[row.user.lower()] = line
            rows.append(row)
            if len(problems) >= MAX_PROBLEMS:
                break
    except csv.Error as exc:
        problems.append(f"line {reader.line_num}: {exc}")
    if problems:
        raise RosterError(problems[:MAX_PROBLEMS])
    if not rows:
        raise RosterError(["the file names nobody: a header and no rows"])
    return rows


def _row(line: int, cells: dict[str, str], problems: list[str]) -> RosterRow | None:
    user = cells.get("user", "")
    try:
        check_ident("user", user)
    except ValueError as exc:
        problems.append(f"line {line}: {exc}")
        return None
    if user.lower() in RESERVED_NAMES:
        problems.append(f"line {line}: the name {user} is reserved")
        return None
    role = (cells.get("role") or "student").lower()
    if role not in ROLES:
        problems.append(f"line {line}: role {role!r} for {user}: one of {', '.join(ROLES)}")
        return None
    long = [c for c in ("name", "email", "team") if len(cells.get(c, "")) > MAX_TEXT]
    if long:
        problems.append(f"line {line}: {', '.join(long)} longer than {MAX_TEXT} characters")
        return None
    return RosterRow(
        line=line,
        user=user,
        name=cells.get("name", ""),
        email=cells.get("email", ""),
        role=role,
        team=cells.get("team", ""),
    )
