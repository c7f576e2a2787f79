"""Which model a dry run simulates a real robot by: its twin, asked of the registry.

The registry keeps the real robots' twins (services/registry/twins.py); a runner,
wherever it runs, asks it over ``registry/twins`` with its service session, and
keeps each answer a few seconds (a class's dry runs come together, and a twin just
saved is in use within that time). A registry that does not answer, or a twin it
sends that does not check, leaves the datasheet's model, and the run's model line
says why.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import zenoh

from common import keys
from common.ask import Seal, ask
from common.lab_errors import LabError
from common.messages import TwinQuery, TwinReply
from common.twin.twinfile import Twin, TwinFileError, parse_twin

log = logging.getLogger("wart.runner.twins")

CACHE_S = 5.0  # an answer is used this long; a twin saved is in use within it
ASK_TIMEOUT_S = 1.0  # a dry run waits no longer for a registry that does not answer


@dataclass(frozen=True)
class TwinChoice:
    """The twin to simulate (None: the datasheet's model), and why not when there is none."""

    twin: Twin | None
    why_not: str = ""  # "" when no twin is kept (the datasheet's is the lab's model then)


class TwinLookup:
    """The twin in force of each real robot, asked of the registry and kept CACHE_S."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        seal: Seal,
        *,
        cache_s: float = CACHE_S,
        timeout: float = ASK_TIMEOUT_S,
    ) -> None:
        self.session = session
        self.key = keys.registry_twins(realm)
        self.seal = seal
        self.cache_s = cache_s
        self.timeout = timeout
        self._known: dict[tuple[str, str], tuple[float, TwinChoice]] = {}
        self._lock = threading.Lock()

    def twin_of(self, arena: str, robot: str) -> TwinChoice:
        """The twin in force for ``arena``'s ``robot`` (the arena's agent context)."""
        now = time.monotonic()
        with self._lock:
            kept = self._known.get((arena, robot))
        if kept is not None and now - kept[0] < self.cache_s:
            return kept[1]
        choice = self._ask(arena, robot)
        with self._lock:
            self._known[(arena, robot)] = (now, choice)
        return choice

    def _ask(self, arena: str, robot: str) -> TwinChoice:
        try:
            reply = ask(
                self.session,
                self.key,
                TwinQuery(robot=robot, arena=arena),
                TwinReply,
                what=f"{robot}'s twin",
                timeout=self.timeout,
                seal=self.seal,
            )
        except LabError as exc:  # no answer, a refusal, no session yet
            log.warning("dry runs on %s use the datasheet's model: %s", robot, exc)
            return TwinChoice(None, f"the registry did not give {robot}'s twin")
        if reply.current is None:
            return TwinChoice(None)
        try:
            return TwinChoice(parse_twin(reply.current.document, f"{robot}'s twin"))
        except TwinFileError as exc:
            log.warning("%s's twin from the registry refused: %s", robot, exc)
            return TwinChoice(None, f"{robot}'s twin did not check")
