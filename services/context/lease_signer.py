"""The leases an agent context signs: one publisher per agent, MAC keys when the world has
an identity.

A lease names its holder (the requester's session for remote control, the
runner's for a deployed controller) and its end; it is republished every
second so a world that restarts learns it again, and republished with an
earlier end to end it at once. When the world's snapshot carries an identity
token the registry signed with the ``world`` permission, each lease also
carries a fresh per-lease key sealed to the holder and to that world
(common/world/leasemac.py), so the holder's commands are MACed (µs to check)
rather than signed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import msgspec
import zenoh

from common import keys, qos
from common.auth import AuthError, Verifier
from common.messages import Lease, Message, SessionToken, SignedToken
from common.world.leasemac import check_world_token, seal_key
from services.context.agent_queue import RunningJob


class LeaseSigner:
    """Publishes the leases of one world's agents, sealed with the context's session."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        world: str,
        seal: Callable[[str, Message], bytes],
        verifier: Verifier,
        log: logging.Logger,
    ) -> None:
        self.session = session
        self.realm = realm
        self.world = world
        self.seal = seal
        self.verifier = verifier
        self.log = log
        self._pubs: dict[str, zenoh.Publisher] = {}
        self.world_token: SessionToken | None = None  # verified; lease keys are sealed to it

    def note_world_identity(self, identity: SignedToken | None) -> None:
        """Keep the world's verified identity token, or none: lease keys are sealed only to it."""
        token: SessionToken | None = None
        if identity is not None:
            try:
                token = check_world_token(self.verifier, identity, self.world)
            except AuthError as exc:
                self.log.warning("world %s identity refused (no MAC leases): %s", self.world, exc)
        previous = self.world_token
        if token is not None and (previous is None or previous.box_key != token.box_key):
            self.log.info("world %s runs as %s: leases carry MAC keys", self.world, token.user)
        self.world_token = token

    def publish(self, run: RunningJob, end: float, holder_user: str) -> None:
        """The lease of ``run``, in force until ``end`` (now, to end it)."""
        agent = run.job.agent
        key = keys.agent_lease(self.realm, self.world, agent)
        pub = self._pubs.get(agent)
        if pub is None:
            pub = self._pubs[agent] = self.session.declare_publisher(
                key, **qos.of(keys.agent_lease)
            )
        lease = Lease(
            lease_id=run.lease_id,
            world=self.world,
            agent=agent,
            holder_user=holder_user,
            holder_session=run.holder_session,
            start=max(run.start, run.lease_start),  # a run handed back: from the hand-back
            end=end,
            requester_session=run.job.session_id,
        )
        sealed = self.lease_keys(run)
        if sealed is not None:
            lease = msgspec.structs.replace(
                lease, holder_key=sealed[0], world_key=sealed[1], world_box=sealed[2]
            )
        try:
            pub.put(self.seal(key, lease))
        except Exception as exc:
            self.log.warning("could not publish the lease of %s: %s", agent, exc)

    def lease_keys(self, run: RunningJob) -> tuple[bytes, bytes, bytes] | None:
        """The MAC lease fields: K sealed to the holder and to the world's verified identity.

        (holder's copy, world's copy, the world box key sealed to); None when
        the world has no (valid, unexpired) identity: the holder then
        signs its commands, as every world understands.
        """
        world = self.world_token
        if world is None or world.expires_at <= time.time() or len(run.holder_box) != 32:
            return None
        cache = (run.holder_box, world.box_key)
        sealed = run.sealed.get(cache)
        if sealed is None:
            sealed = (
                seal_key(run.lease_key, run.holder_box),
                seal_key(run.lease_key, world.box_key),
            )
            run.sealed[cache] = sealed
        return sealed[0], sealed[1], world.box_key

    def close(self) -> None:
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
