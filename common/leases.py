"""Who may drive which agent: the lease and command checks every world shares.

A world (the Sim2D engine, the Khepera bridge) accepts a ``Lease`` sealed by a
principal with the ``lease`` permission (the agent context) and obeys an
``AgentCommand`` only from the session that holds the agent's current lease,
within its start..end (the world's wall clock). Both worlds use this one
class, so a controller cannot tell a simulated robot from a real one by what
it is allowed to do.

Thread safety: the lease table has its own lock; Zenoh callback threads call
:meth:`LeaseBook.accept_lease` and :meth:`LeaseBook.check_command` while the
world's own thread reads :meth:`LeaseBook.in_force`.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from common import keys
from common.auth import AuthError, Principal, Verifier
from common.messages import AgentCommand, Lease


class LeaseBook:
    """The current lease of each agent of one world, and the checks that use it."""

    def __init__(self, realm: str, world: str, verifier: Verifier | None) -> None:
        self.realm, self.world, self.verifier = realm, world, verifier
        self._leases: dict[str, Lease] = {}
        self._lock = threading.Lock()
        self.commands_accepted = 0
        self.commands_refused = 0

    def _open(self, key: str, payload: Any, expected: Any) -> tuple[Principal, Any]:
        if self.verifier is None:
            raise AuthError("unauthenticated", "this world was started without --registry-key")
        return self.verifier.open(key, payload, expected)

    def accept_lease(self, key: str, payload: Any) -> Lease:
        """Verify a sealed Lease put on ``key`` and record it; AuthError/MessageError if refused.

        A lease with the same id replaces the earlier one (a lease ended early
        is republished with a new end); otherwise the one with the later start
        wins, so a late republication of an old lease cannot undo a newer one.
        """
        principal, lease = self._open(key, payload, Lease)
        principal.require("lease", "grant leases on agents")
        agent = keys.parse_agent_key(self.realm, self.world, key)
        if lease.world != self.world or lease.agent != agent:
            raise AuthError("forbidden", f"lease for {lease.world}/{lease.agent} sent on {key}")
        with self._lock:
            current = self._leases.get(lease.agent)
            if (
                current is None
                or current.lease_id == lease.lease_id
                or lease.start >= current.start
            ):
                self._leases[lease.agent] = lease
        return lease

    def lease_of(self, agent: str) -> Lease | None:
        with self._lock:
            return self._leases.get(agent)

    def in_force(self, agent: str, now: float | None = None) -> Lease | None:
        """The agent's lease if it is in force at ``now`` (wall clock), else None."""
        lease = self.lease_of(agent)
        t = time.time() if now is None else now
        if lease is not None and lease.start <= t <= lease.end:
            return lease
        return None

    def check_command(self, key: str, payload: Any) -> tuple[str, AgentCommand]:
        """The agent and command of a sealed AgentCommand the world must obey.

        Raises AuthError (or MessageError for a malformed payload) for anything
        else: unsigned, for another agent, no lease, not the holder, outside
        the lease. Counted in ``commands_accepted`` / ``commands_refused``.
        """
        agent = keys.parse_agent_key(self.realm, self.world, key)
        try:
            principal, command = self._open(key, payload, AgentCommand)
            if agent is None or command.agent != agent:
                raise AuthError("forbidden", f"command for {command.agent} sent on {key}")
            lease = self.lease_of(agent)
            now = time.time()
            if lease is None:
                raise AuthError("forbidden", f"{agent} has no lease: command dropped")
            if principal.session_id != lease.holder_session:
                raise AuthError("forbidden", f"{principal.user} does not hold {agent}'s lease")
            if not lease.start <= now <= lease.end:
                raise AuthError("forbidden", f"{principal.user}'s lease on {agent} is not in force")
        except Exception:
            self.commands_refused += 1
            raise
        self.commands_accepted += 1
        return agent, command
