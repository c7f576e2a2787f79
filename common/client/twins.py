"""The lab's twins as a client asks for them: the registry's ``registry/twins``, sealed.

A LabClient's part (``client.twins``): ``wart twin``, ``wart calibrate --save`` and
the page ask through it; the registry says who may read and who may save
(services/registry/twins.py). Each call raises a LabError in the user's words: not
allowed, no answer (is the registry running?), a twin file refused with every
problem named.
"""

from __future__ import annotations

from common import keys
from common.client.client_ask import ClientAsk
from common.messages import (
    TwinList,
    TwinListed,
    TwinListQuery,
    TwinQuery,
    TwinReply,
    TwinSave,
    TwinSaved,
)


class TwinCalls:
    """The real robots' twins the registry keeps, read and saved."""

    def __init__(self, realm: str, ask: ClientAsk) -> None:
        self.key = keys.registry_twins(realm)
        self._ask = ask

    def robots(self) -> list[TwinListed]:
        """Each robot with a kept twin, its versions and the line of the one in force."""
        return self._ask(self.key, TwinListQuery(), TwinList, "list the robots' twins").robots

    def of(self, robot: str, arena: str | None = None, *, history: bool = False) -> TwinReply:
        """The twin in force of ``arena``'s ``robot`` (its own, else one kept for no arena;
        ``current`` None: none kept); ``history``: a line for every version of it too."""
        request = TwinQuery(robot=robot, history=history, arena=arena)
        where = f" in {arena}" if arena else ""
        return self._ask(self.key, request, TwinReply, f"read {robot}'s twin{where}")

    def save(self, document: str, robot: str, arena: str | None = None) -> TwinSaved:
        """Keep a twin file's text as the newest version of ``arena``'s robot's twin, in
        force at once; ``arena``: the arena the saver owns, the robot's (a lab admin may
        name none: a twin for no arena)."""
        request = TwinSave(document=document, arena=arena)
        return self._ask(self.key, request, TwinSaved, f"keep {robot}'s twin")
