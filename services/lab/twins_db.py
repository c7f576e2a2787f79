"""Real robots' twins in the lab's database: each robot's fits, versioned, the newest in force.

A twin (common/twin/twinfile.py) is kept with who saved it and when, beside who
fitted it, when and from which runs; saving a robot's twin again adds a version
and keeps the older ones (a teacher compares, or goes back with ``wart twin
save`` of an older file). The lab's database (services/lab/database.py) is where
the lab keeps its accounts and courses; the registry alone opens it for twins and
serves them (services/registry/twins.py): ``wart calibrate --save``, ``wart twin``
and the runners' dry runs ask the registry. ``wart report --db`` reads it offline.

Every row read back is checked again as a twin file: a row written by hand into
the database is refused as a file from a user would be.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from common.twin.twinfile import Twin, TwinFileError, parse_twin
from services.lab.database import DbError, LabDatabase

SCHEMA = """
CREATE TABLE IF NOT EXISTS twins (
    robot TEXT NOT NULL,
    version INTEGER NOT NULL,
    saved_by TEXT NOT NULL,
    saved_at REAL NOT NULL,
    fitted_by TEXT NOT NULL,
    fitted_at REAL NOT NULL,
    document TEXT NOT NULL,
    PRIMARY KEY (robot, version)
);
"""


@dataclass(frozen=True)
class StoredTwin:
    """One version of a robot's twin, as kept."""

    version: int
    saved_by: str
    saved_at: float
    twin: Twin

    def line(self) -> str:
        t = self.twin
        saved = time.strftime("%Y-%m-%d %H:%M", time.gmtime(self.saved_at))
        return (
            f"v{self.version}: fitted {t.day} by {t.fitted_by} from {', '.join(t.runs)}; "
            f"saved {saved} UTC by {self.saved_by}"
        )


class TwinStore:
    """The ``twins`` table of the lab's database (created on first use)."""

    def __init__(self, database: LabDatabase) -> None:
        self.database = database
        database.create(SCHEMA, "twin table")

    @classmethod
    def open(cls, path: Path) -> TwinStore:
        """The lab's database at ``path``; one that is not there is refused, never made
        (a mistyped path would keep a twin where no runner looks)."""
        if not path.is_file():
            raise DbError("not_found", f"no lab database at {path} (the registry's --db)")
        return cls(LabDatabase(path, "lab"))

    def close(self) -> None:
        self.database.close()

    def save(self, twin: Twin, saved_by: str, now: float | None = None) -> int:
        """Keep ``twin`` as its robot's newest version; its version number."""
        when = time.time() if now is None else now
        with self.database.transaction() as c:
            (last,) = c.execute(
                "SELECT COALESCE(MAX(version), 0) FROM twins WHERE robot = ?", (twin.robot,)
            ).fetchone()
            version = int(last) + 1
            c.execute(
                "INSERT INTO twins VALUES (?, ?, ?, ?, ?, ?, ?)",
                (twin.robot, version, saved_by, when, twin.fitted_by, twin.fitted_at, twin.text),
            )
        return version

    def versions(self, robot: str) -> list[StoredTwin]:
        """Every kept version of ``robot``'s twin, oldest first."""
        rows = self.database.rows(
            "SELECT version, saved_by, saved_at, document FROM twins WHERE robot = ? "
            "ORDER BY version",
            robot,
        )
        return [self._stored(robot, *row) for row in rows]

    def current(self, robot: str) -> StoredTwin | None:
        """The twin in force for ``robot`` (its newest version), or None."""
        rows = self.database.rows(
            "SELECT version, saved_by, saved_at, document FROM twins WHERE robot = ? "
            "ORDER BY version DESC LIMIT 1",
            robot,
        )
        return self._stored(robot, *rows[0]) if rows else None

    def count(self, robot: str) -> int:
        """How many versions of ``robot``'s twin are kept (none read)."""
        rows = self.database.rows("SELECT COUNT(*) FROM twins WHERE robot = ?", robot)
        return int(rows[0][0]) if rows else 0

    def robots(self) -> list[tuple[str, int]]:
        """Each robot with a twin, and how many versions it has."""
        rows = self.database.rows("SELECT robot, COUNT(*) FROM twins GROUP BY robot ORDER BY robot")
        return [(str(r), int(n)) for r, n in rows]

    @staticmethod
    def _stored(robot: str, version: int, saved_by: str, saved_at: float, doc: str) -> StoredTwin:
        try:
            twin = parse_twin(doc, f"{robot}'s twin v{version} in the lab's database")
        except TwinFileError as exc:
            raise DbError("internal", str(exc)) from None
        return StoredTwin(int(version), str(saved_by), float(saved_at), twin)
