"""The registry's twin desk: real robots' twins served over ``registry/twins``, sealed.

The twins are kept in the registry's own database (services/lab/twins_db.py), so
a runner on another machine, or in its own pod, asks here instead of opening a
file it does not have.

Twins are kept by arena (an agent context) and robot. Who may read a twin: the
runners' service accounts (a dry run simulates the robot by it), teachers
(``edit_map``: they calibrate the lab's robots), lab admins, whoever owns a live arena
(an agent context in the directory), and a course's teachers (a course role, without
``edit_map``) the twins of their course's arenas: the live arenas whose owner teaches
one of their courses. Who may save one: the owner of the arena the request names, for a
robot of that arena (the context's robots, as the directory has them), or a lab admin;
each save, and each refused save, is a line of the audit trail. A document is checked field by field
before it is kept (a refusal names every problem), and every row read back is
checked again as a twin file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping

import zenoh

from common.acl import SERVICE_ACCOUNT_PREFIX
from common.auth import AuthError, Principal, Verifier
from common.messages import (
    MAX_HISTORY,
    ContextInfo,
    Message,
    TwinList,
    TwinListed,
    TwinListQuery,
    TwinQuery,
    TwinReply,
    TwinSave,
    TwinSaved,
    TwinVersion,
)
from common.service import RequestError
from common.twin.twinfile import TwinFileError, parse_twin
from services.lab.database import DbError
from services.lab.twins_db import LAB_WIDE, StoredTwin, TwinStore
from services.registry.admin import source_of
from services.registry.audit_db import Action

log = logging.getLogger("wart.registry.twins")

# The directory's live contexts by name (the registry's own, kept current).
Contexts = Callable[[], Mapping[str, ContextInfo]]
READERS = "runners, teachers, lab admins, arena owners and the teachers of an arena's course"


class TwinDesk:
    """Answers TwinQuery, TwinListQuery and TwinSave from the twins table."""

    def __init__(
        self,
        store: TwinStore,
        verifier: Verifier,
        contexts: Contexts,
        audit: Callable[[Action], None],
    ) -> None:
        self.store = store
        self.verifier = verifier
        self.contexts = contexts
        self.audit = audit

    def on_twins(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(
            str(query.key_expr), query.payload, (TwinQuery, TwinListQuery, TwinSave)
        )
        try:
            if isinstance(request, TwinSave):
                return self._save(principal, request, source_of(query))
            if self.may_read(principal):
                if isinstance(request, TwinListQuery):
                    return self._list(None)
                return self._query(request)
            # A course's teacher: the twins of the course's arenas only.
            courses = self.course_arenas(principal.user)
            if isinstance(request, TwinListQuery) and courses:
                return self._list(courses)
            if isinstance(request, TwinQuery) and request.arena in courses:
                return self._query(request)
            if isinstance(request, TwinQuery) and request.arena is not None and courses:
                raise AuthError(
                    "forbidden",
                    f"{principal.user} may not read the twins of arena {request.arena}: it is "
                    f"not an arena of a course {principal.user} teaches (those running now: "
                    f"{', '.join(sorted(courses))})",
                )
            raise AuthError(
                "forbidden", f"{principal.user} may not read the robots' twins ({READERS} may)"
            )
        except DbError as exc:
            raise RequestError(exc.code, exc.message) from None

    def arena_owners(self) -> dict[str, str]:
        """The owner of each live agent context (a real or simulated arena), by name."""
        return {c.ctx: c.owner for c in self.contexts().values() if c.kind == "agent"}

    def course_arenas(self, user: str) -> set[str]:
        """The live arenas of the courses ``user`` teaches: those whose owner teaches one."""
        mine = self.store.teaching(user)
        if not mine:
            return set()
        owners = self.arena_owners().items()
        return {ctx for ctx, owner in owners if mine & self.store.teaching(owner)}

    def may_read(self, principal: Principal) -> bool:
        """Whether ``principal`` reads every twin (a course's teacher reads some)."""
        runner = principal.user.startswith(SERVICE_ACCOUNT_PREFIX["runner"])
        return (
            (runner and principal.has("lease"))
            or principal.has("edit_map")
            or principal.has("admin")
            or principal.user in self.arena_owners().values()
        )

    def _query(self, request: TwinQuery) -> TwinReply:
        robot = request.robot
        where = self.store.in_force(request.arena or LAB_WIDE, robot)
        if where is None:
            return TwinReply(robot=robot, arena=request.arena)
        versions = self.store.versions(where, robot) if request.history else []
        current = versions[-1] if versions else self.store.current(where, robot)
        return TwinReply(
            robot=robot,
            arena=where or None,
            current=None if current is None else _wire(current),
            history=[v.line()[:256] for v in versions[-MAX_HISTORY:]],
            versions=len(versions) if request.history else self.store.count(where, robot),
        )

    def _list(self, arenas: set[str] | None) -> TwinList:
        """Every kept twin; ``arenas``: only theirs."""
        listed = []
        for arena, robot, count in self.store.robots():
            if arenas is not None and arena not in arenas:
                continue
            current = self.store.current(arena, robot)
            if current is not None:
                line = current.line()[:256]
                listed.append(
                    TwinListed(robot=robot, versions=count, current=line, arena=arena or None)
                )
        return TwinList(robots=listed)

    def _save(self, principal: Principal, request: TwinSave, source: str) -> TwinSaved:
        try:
            twin = parse_twin(request.document, "the twin sent")
        except TwinFileError as exc:
            raise RequestError("bad_request", f"refused, nothing kept:\n{exc}") from None
        target = f"twin/{request.arena}/{twin.robot}" if request.arena else f"twin/{twin.robot}"
        if not principal.has("admin"):
            where = self._why_not_keep(principal.user, request.arena, twin.robot)
            if where:
                self.audit(Action(principal.user, "twin_save", target, "refused", where, source))
                raise AuthError(
                    "forbidden", f"{principal.user} may not keep {twin.robot}'s twin: {where}"
                )
        version = self.store.save(request.arena or LAB_WIDE, twin, principal.user)
        model = twin.model()
        self.audit(
            Action(principal.user, "twin_save", target, "ok", f"v{version}: {model}", source)
        )
        log.info("%s kept %s as v%d for %s", principal.user, model, version, target)
        return TwinSaved(robot=twin.robot, version=version, model=model[:256], arena=request.arena)

    def _why_not_keep(self, user: str, arena: str | None, robot: str) -> str:
        """Why ``user`` (no lab admin) may not keep ``arena``'s ``robot``'s twin; "" if they may."""
        owners = "(the arena's owner or a lab admin keeps a twin)"
        if arena is None:
            return f"name the arena you own {owners}"
        info = self.contexts().get(arena)
        if info is None or info.kind != "agent" or info.owner != user:
            return f"arena {arena} is not yours (or not running) {owners}"
        if robot not in info.robots:
            robots = ", ".join(info.robots) or "none yet"
            return f"arena {arena} has no robot {robot} (its robots: {robots})"
        return ""


def _wire(stored: StoredTwin) -> TwinVersion:
    return TwinVersion(
        version=stored.version,
        saved_by=stored.saved_by,
        saved_at=stored.saved_at,
        document=stored.twin.text,
    )
