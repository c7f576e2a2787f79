"""Real robots' twins in the lab's database: each arena's robot's fits, versioned, the newest
in force.

A twin (common/twin/twinfile.py) is kept by arena (the real arena's agent context) and
robot, with who saved it and when, beside who fitted it, when and from which runs;
two arenas' k1 are two robots. Saving a robot's twin again adds a version
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
from services.lab.database import ROSTER_SCHEMA, DbError, LabDatabase

# Keyed by arena (the real arena's agent context) and robot: two arenas' k1 are two
# robots. Arena '': a twin kept before twins were per arena (or a lab admin's for no
# arena in particular), in force for a robot of that name in any arena without its own.
LAB_WIDE = ""
COLUMNS = "arena, robot, version, saved_by, saved_at, fitted_by, fitted_at, document"
SCHEMA = """
CREATE TABLE IF NOT EXISTS twins (
    arena TEXT NOT NULL,
    robot TEXT NOT NULL,
    version INTEGER NOT NULL,
    saved_by TEXT NOT NULL,
    saved_at REAL NOT NULL,
    fitted_by TEXT NOT NULL,
    fitted_at REAL NOT NULL,
    document TEXT NOT NULL,
    PRIMARY KEY (arena, robot, version)
);
"""


@dataclass(frozen=True)
class StoredTwin:
    """One version of a robot's twin, as kept."""

    arena: str  # LAB_WIDE: kept for no arena in particular
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

    @property
    def where(self) -> str:
        """Which arena's it is, in words."""
        return f"arena {self.arena}" if self.arena else "any arena (kept lab-wide)"


class TwinStore:
    """The ``twins`` table of the lab's database (created on first use; a table from
    before twins were per arena is moved over, its rows kept lab-wide)."""

    def __init__(self, database: LabDatabase) -> None:
        self.database = database
        columns = database.columns("twins")
        if columns and "arena" not in columns:
            with database.transaction() as c:
                c.execute("ALTER TABLE twins RENAME TO twins_by_robot")
                c.execute(SCHEMA)
                c.execute(
                    f"INSERT INTO twins ({COLUMNS}) SELECT ?, robot, version, saved_by, "
                    "saved_at, fitted_by, fitted_at, document FROM twins_by_robot",
                    (LAB_WIDE,),
                )
                c.execute("DROP TABLE twins_by_robot")
        database.create(SCHEMA, "twin table")
        # The roster is the registry's (courses_db); created here too, for teaching().
        database.create(ROSTER_SCHEMA, "course tables")

    @classmethod
    def open(cls, path: Path) -> TwinStore:
        """The lab's database at ``path``; one that is not there is refused, never made
        (a mistyped path would keep a twin where no runner looks)."""
        if not path.is_file():
            raise DbError("not_found", f"no lab database at {path} (the registry's --db)")
        return cls(LabDatabase(path, "lab"))

    def close(self) -> None:
        self.database.close()

    def save(self, arena: str, twin: Twin, saved_by: str, now: float | None = None) -> int:
        """Keep ``twin`` as the newest version of ``arena``'s robot's; its version number."""
        when = time.time() if now is None else now
        with self.database.transaction() as c:
            (last,) = c.execute(
                "SELECT COALESCE(MAX(version), 0) FROM twins WHERE arena = ? AND robot = ?",
                (arena, twin.robot),
            ).fetchone()
            version = int(last) + 1
            c.execute(
                f"INSERT INTO twins ({COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (arena, twin.robot, version, saved_by, when, twin.fitted_by, twin.fitted_at,
                 twin.text),
            )  # fmt: skip
        return version

    def versions(self, arena: str, robot: str) -> list[StoredTwin]:
        """Every kept version of ``arena``'s ``robot``'s twin (just that arena's), oldest first."""
        rows = self.database.rows(
            "SELECT arena, version, saved_by, saved_at, document FROM twins "
            "WHERE arena = ? AND robot = ? ORDER BY version",
            arena,
            robot,
        )
        return [self._stored(robot, *row) for row in rows]

    def in_force(self, arena: str, robot: str) -> str | None:
        """Whose twin is in force for ``arena``'s ``robot``: the arena's own, else one kept
        lab-wide (LAB_WIDE), else None."""
        rows = self.database.rows(
            "SELECT arena FROM twins WHERE robot = ? AND arena IN (?, ?) "
            "ORDER BY arena = ? DESC LIMIT 1",
            robot,
            arena,
            LAB_WIDE,
            arena,
        )
        return str(rows[0][0]) if rows else None

    def current(self, arena: str, robot: str) -> StoredTwin | None:
        """The twin in force for ``arena``'s ``robot`` (the newest version of the arena's
        own, else of one kept lab-wide), or None."""
        where = self.in_force(arena, robot)
        if where is None:
            return None
        rows = self.database.rows(
            "SELECT arena, version, saved_by, saved_at, document FROM twins "
            "WHERE arena = ? AND robot = ? ORDER BY version DESC LIMIT 1",
            where,
            robot,
        )
        return self._stored(robot, *rows[0]) if rows else None

    def count(self, arena: str, robot: str) -> int:
        """How many versions of ``arena``'s ``robot``'s twin are kept (none read)."""
        rows = self.database.rows(
            "SELECT COUNT(*) FROM twins WHERE arena = ? AND robot = ?", arena, robot
        )
        return int(rows[0][0]) if rows else 0

    def teaching(self, user: str) -> frozenset[str]:
        """The courses ``user`` is a teacher of (the course roles a roster gives): a course's
        teachers read the twins of its arenas."""
        rows = self.database.rows(
            "SELECT course FROM course_members WHERE user = ? AND role = 'teacher'", user
        )
        return frozenset(str(r[0]) for r in rows)

    def robots(self) -> list[tuple[str, str, int]]:
        """Each (arena, robot) with a twin, and how many versions it has."""
        rows = self.database.rows(
            "SELECT arena, robot, COUNT(*) FROM twins GROUP BY arena, robot ORDER BY arena, robot"
        )
        return [(str(a), str(r), int(n)) for a, r, n in rows]

    @staticmethod
    def _stored(
        robot: str, arena: str, version: int, saved_by: str, saved_at: float, doc: str
    ) -> StoredTwin:
        where = f" of arena {arena}" if arena else ""
        try:
            twin = parse_twin(doc, f"{robot}'s twin{where} v{version} in the lab's database")
        except TwinFileError as exc:
            raise DbError("internal", str(exc)) from None
        return StoredTwin(str(arena), int(version), str(saved_by), float(saved_at), twin)
