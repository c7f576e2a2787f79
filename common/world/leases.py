"""Who may drive which agent: the lease and command checks every world shares.

A world (the Sim2D engine, the Khepera bridge) accepts a ``Lease`` sealed by a
principal with the ``lease`` permission (the agent context) and obeys an
``AgentCommand`` only from the session that holds the agent's current lease,
within its start..end (the world's wall clock). Both worlds use this one
class, so a controller cannot tell a simulated robot from a real one by what
it is allowed to do.

A command is either an Ed25519 ``AuthEnvelope`` (any world) or, under a MAC
lease, a ``MacCommand`` keyed with the lease key the context sealed to this
world (common/world/leasemac.py): only for worlds with an identity (``box_keys``).

Thread safety: the lease table has its own lock; Zenoh callback threads call
:meth:`LeaseBook.accept_lease` and :meth:`LeaseBook.check_command` while the
world's own thread reads :meth:`LeaseBook.in_force`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from common import keys
from common.auth import AuthError, Principal, ReplayWindow, Verifier
from common.messages import (
    MAC_ITEM_BYTES,
    MAC_ITEM_COUNTERS,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    AgentCommand,
    AuthEnvelope,
    BundledCommand,
    Lease,
    MacCommand,
    MacCommandBundle,
    MessageError,
    WorldStop,
    decode,
)
from common.world.leasemac import (
    MAC_BYTES,
    CommandMac,
    WorldBoxKeys,
    command_mac,
    mac_matches,
    open_key,
)

log = logging.getLogger("wart.leases")
# Stop, then Reset: the last holder may still reset a robot nobody holds this long after.
RESET_AFTER_STOP_S = 60.0


class LeaseBook:
    """The current lease of each agent of one world, and the checks that use it."""

    def __init__(
        self,
        realm: str,
        world: str,
        verifier: Verifier | None,
        box_keys: WorldBoxKeys | None = None,
    ) -> None:
        self.realm, self.world, self.verifier = realm, world, verifier
        self.box_keys = box_keys  # this world's identity: opens lease keys sealed to it
        self._leases: dict[str, Lease] = {}
        # agent -> lease id, K, seqs, and K's MAC on the agent's command key (prefix hashed once)
        self._mac: dict[str, tuple[str, bytes, ReplayWindow, CommandMac]] = {}
        # Command key -> agent, for agents that ever held a lease here: the 50 Hz
        # check skips parsing and re-validating the key (bounded by the world's agents).
        self._agent_of: dict[str, str] = {}
        self._key_of: dict[str, str] = {}  # and back: a bundled command's agent -> its key
        self._lock = threading.Lock()
        # This world's epoch: the replay windows live in memory, so after a restart a
        # command sealed before it would look fresh again (the context republishes the
        # lease, and reseals its key to the restarted world). Nothing sealed before the
        # world started is obeyed: senders' clocks are trusted to ±30 s already.
        self.started_at = time.time()
        # The emergency stop in force ("" when none): while set, no lease is accepted
        # and no command obeyed. _stop_sent is the newest stop's send time obeyed,
        # so a stop or release delivered late cannot undo a newer one.
        self.stopped = ""
        self._stop_sent = 0.0
        self.commands_accepted = 0
        self.commands_refused = 0
        self.mac_accepted = 0  # of commands_accepted, those MACed under a MAC lease

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
        if self.stopped and lease.end > time.time():
            raise AuthError("forbidden", f"lease {lease.lease_id} refused: {self.stopped}")
        assert self.verifier is not None
        if self.verifier.is_revoked(lease.holder_session):
            raise AuthError(
                "forbidden",
                f"lease {lease.lease_id} is held by a revoked session of {lease.holder_user}",
            )
        agent = keys.parse_agent_key(self.realm, self.world, key)
        if lease.world != self.world or lease.agent != agent:
            raise AuthError("forbidden", f"lease for {lease.world}/{lease.agent} sent on {key}")
        lease_key = self._lease_key(lease)
        cmd_key = self.command_key(lease.agent)
        with self._lock:
            current = self._leases.get(lease.agent)
            if (
                current is None
                or current.lease_id == lease.lease_id
                or lease.start >= current.start
            ):
                self._leases[lease.agent] = lease
                if current is None or current.lease_id != lease.lease_id:
                    # One line a slot (republications keep the id): an operator can
                    # tell "the lease never reached this world" from a refused command.
                    log.info(
                        "%s/%s leased to %s until %s (lease %s)",
                        self.world,
                        lease.agent,
                        lease.holder_user,
                        time.strftime("%H:%M:%S", time.localtime(lease.end)),
                        lease.lease_id,
                    )
                mac = self._mac.get(lease.agent)
                if lease_key is None:
                    self._mac.pop(lease.agent, None)
                elif mac is None or mac[0] != lease.lease_id or mac[1] != lease_key:
                    # A new lease (or a new key) starts a new replay window; a
                    # republication of the same one keeps the window it has.
                    self._mac[lease.agent] = (
                        lease.lease_id,
                        lease_key,
                        ReplayWindow(lease.end),
                        CommandMac(lease_key, cmd_key, lease.lease_id),
                    )
                self._agent_of[cmd_key] = lease.agent
                self._key_of[lease.agent] = cmd_key
        return lease

    def accept_stop(self, key: str, payload: Any) -> WorldStop | None:
        """Verify a sealed WorldStop put on ``key`` and obey it; None if it changes nothing.

        AuthError if refused: unsigned, without ``lease``, sealed before this
        world started (a stop captured before a restart), or replayed (the
        verifier's window). Engaging drops every lease: their holders' commands
        are refused from here on, whatever their ``end``.
        """
        if self.verifier is None:
            raise AuthError("unauthenticated", "this world was started without --registry-key")
        try:
            envelope = decode(payload, AuthEnvelope)
        except MessageError as exc:
            self.verifier.rejected += 1
            raise AuthError("unauthenticated", f"not an authenticated stop: {exc}") from None
        self._check_epoch(envelope.sent_at, "(emergency stop)")
        principal, stop = self.verifier.open_envelope(key, envelope, WorldStop)
        principal.require("lease", "stop a world")
        with self._lock:
            if envelope.sent_at <= self._stop_sent:
                return None  # older than the stop or release already obeyed
            self._stop_sent = envelope.sent_at
            was = self.stopped
            if stop.engaged:
                self.stopped = stop.reason or f"emergency stop by {stop.by}"
                self._leases.clear()
                self._mac.clear()
            else:
                self.stopped = ""
            if bool(was) == stop.engaged:
                return None  # a republication of the state in force
        return stop

    def revoke_session(self, session_id: bytes) -> list[str]:
        """Drop every lease held by a revoked session: the agents it held, now undriven."""
        with self._lock:
            agents = [a for a, lease in self._leases.items() if lease.holder_session == session_id]
            for agent in agents:
                del self._leases[agent]
                self._mac.pop(agent, None)
        return agents

    def command_key(self, agent: str) -> str:
        """``agent/<agent>/cmd`` of this world; BadIdentifier (a ValueError) for a bad name."""
        return keys.agent_cmd(self.realm, self.world, agent)

    def _lease_key(self, lease: Lease) -> bytes | None:
        """This world's copy of the lease key, if the lease carries one it can open."""
        if lease.world_key is None or lease.world_box is None or self.box_keys is None:
            return None
        private = self.box_keys.private_for(lease.world_box)
        if private is None:
            # Sealed to a box key this world never had (it restarted, with a new
            # session): Ed25519 commands only, until the context reseals.
            log.info("lease %s: key sealed to another identity of %s", lease.lease_id, self.world)
            return None
        try:
            return open_key(lease.world_key, private)
        except AuthError as exc:
            log.warning("lease %s: %s", lease.lease_id, exc.message)
            return None

    def has_mac_key(self, agent: str) -> bool:
        with self._lock:
            return agent in self._mac

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

    def may_reset(self, principal: Principal, agent: str, now: float | None = None) -> str | None:
        """Why ``principal`` may not reset ``agent`` (None: it may).

        A map editor may; otherwise only the holder of the agent's lease in
        force, or the session that lease serves (the student whose uploaded
        controller the runner drives): a reset is a jump of the robot, and
        only whoever holds it now may make it jump. Stop, then Reset is what a
        student does: the last lease's sessions may still reset a robot nobody
        holds for RESET_AFTER_STOP_S after their lease ended.
        """
        if principal.has("edit_map"):
            return None
        t = time.time() if now is None else now
        lease = self.in_force(agent, t)
        if lease is None:
            last = self.lease_of(agent)
            mine = last is not None and principal.session_id in (
                last.holder_session,
                last.requester_session,
            )
            if last is not None and mine and 0 <= t - last.end <= RESET_AFTER_STOP_S:
                return None
            return (
                f"{agent} is not yours now: reset it while your controller holds it, or within "
                f"{RESET_AFTER_STOP_S:.0f} s after it stops"
            )
        if principal.session_id in (lease.holder_session, lease.requester_session):
            return None
        return (
            f"{agent} is driven by someone else's controller now: only they or a map editor "
            "may reset it"
        )

    def agents_in_force(self, now: float | None = None) -> list[str]:
        """The agents whose lease is in force at ``now`` (wall clock), sorted."""
        t = time.time() if now is None else now
        with self._lock:
            return sorted(a for a, lease in self._leases.items() if lease.start <= t <= lease.end)

    def check_bundle(
        self, items: Sequence[BundledCommand], obey: Callable[[str, AgentCommand], None]
    ) -> list[str]:
        """Check a CommandBundle's commands, ``obey`` each one that passes; why the others failed.

        Each item is checked exactly as :meth:`check_command` checks its
        payload put on its agent's own ``cmd`` key (the key its signature or
        MAC covers): the bundle adds no authority. A refused item spares the
        others, and each command is obeyed as soon as it passed, not after
        the whole bundle. Shared per bundle: only the clock read, and the
        lookup of each agent's key (cached for agents that held a lease here).
        ``obey`` may refuse too (AuthError, e.g. a bridge without that robot).
        """
        refused: list[str] = []
        now = time.time()
        for item in items:
            try:
                key = self._key_of.get(item.agent) or self.command_key(item.agent)
                obey(*self.check_command(key, item.payload, now))
            except (AuthError, MessageError, ValueError) as exc:
                refused.append(f"{item.agent}: {exc}")
        return refused

    def check_mac_bundle(
        self, bundle: MacCommandBundle, obey: Callable[[str, AgentCommand], None]
    ) -> list[str]:
        """Check a MacCommandBundle's items, ``obey`` each one that passes; why the others failed.

        Each item gets the checks a MacCommand on its agent's own ``cmd`` key
        gets (:meth:`_check_mac`), in the same order: the emergency stop; a
        lease for the agent carrying a key this world opened; the item's MAC
        under that lease's key (over the agent's own key expression, the
        lease id and the record's bytes, so an item cannot be moved to
        another agent, lease or time, or altered); the lease in force; sent
        after this world started; fresh (±the verifier's window); flags
        known; and last, the sequence number unseen under that lease (the
        replay window is touched only by an item whose MAC matched). A
        refused item spares the others; each passing one is obeyed at once.

        Shared per bundle, where the per-command path pays per command: one
        decode of the whole bundle, one look at the lease tables under the
        lock, one read of each clock. Lengths that disagree refuse the whole
        bundle (MessageError): nothing in it can be attributed to an item.
        """
        agents, items, macs = bundle.agents, bundle.items, bundle.macs
        n = len(agents)
        if len(items) != n * MAC_ITEM_BYTES or len(macs) != n * MAC_BYTES:
            self.commands_refused += n
            raise MessageError(
                f"MacCommandBundle of {n} agents carries {len(items)} item bytes and "
                f"{len(macs)} MAC bytes (needs {n * MAC_ITEM_BYTES} and {n * MAC_BYTES})"
            )
        verifier = self.verifier
        if verifier is None or self.stopped:
            self.commands_refused += n
            why = (
                "this world was started without --registry-key"
                if verifier is None
                else f"refused: {self.stopped}"
            )
            return [f"{agent}: {why}" for agent in agents]
        now = time.time()
        fresh_now, fresh_window = verifier.clock(), verifier.window
        started = self.started_at
        with self._lock:  # one consistent look at both tables for the whole bundle
            rows = [(self._leases.get(a), self._mac.get(a)) for a in agents]
        refused: list[str] = []
        unpack, compare = MAC_ITEM_STRUCT.unpack_from, mac_matches
        for i, agent in enumerate(agents):
            lease, mac = rows[i]
            try:
                if lease is None:
                    raise AuthError("forbidden", "no lease: command dropped")
                if mac is None or mac[0] != lease.lease_id:
                    raise AuthError(
                        "forbidden",
                        f"lease {lease.lease_id} carries no key for this world: sign commands",
                    )
                at = i * MAC_ITEM_BYTES
                record = items[at : at + MAC_ITEM_BYTES]
                if not compare(mac[3].item_tag(record), macs[i * MAC_BYTES : (i + 1) * MAC_BYTES]):
                    verifier.rejected += 1
                    raise AuthError(
                        "unauthenticated", f"item MAC does not match lease {lease.lease_id}"
                    )
                seq, sent_at, flags, left, right, a, b = unpack(record)
                if not lease.start <= now <= lease.end:
                    raise AuthError("forbidden", f"lease {lease.lease_id} is not in force")
                if sent_at < started:
                    verifier.rejected += 1
                    raise AuthError(
                        "unauthenticated",
                        f"command under lease {lease.lease_id} was sealed before this world "
                        "started",
                    )
                if not abs(fresh_now - sent_at) <= fresh_window:  # NaN too
                    verifier.rejected += 1
                    raise AuthError(
                        "unauthenticated",
                        f"command is {fresh_now - sent_at:+.1f} s off this world's clock "
                        f"(allowed ±{fresh_window:.0f} s): check the clocks, or it is a replay",
                    )
                if flags & ~(MAC_ITEM_SPEEDS | MAC_ITEM_COUNTERS):
                    raise AuthError("bad_request", f"unknown command flags {flags:#x}")
                with self._lock:
                    fresh = mac[2].accept(seq)
                if not fresh:
                    verifier.rejected += 1
                    raise AuthError(
                        "unauthenticated", f"replayed command under lease {lease.lease_id}"
                    )
                command = AgentCommand(
                    agent=agent,
                    speeds=(left, right) if flags & MAC_ITEM_SPEEDS else None,
                    counters=(a, b) if flags & MAC_ITEM_COUNTERS else None,
                )
            except AuthError as exc:
                self.commands_refused += 1
                refused.append(f"{agent}: {exc}")
                continue
            self.commands_accepted += 1
            self.mac_accepted += 1
            try:
                obey(agent, command)
            except (AuthError, ValueError) as exc:  # e.g. a bridge without that robot
                refused.append(f"{agent}: {exc}")
        return refused

    def check_command(
        self, key: str, payload: Any, now: float | None = None
    ) -> tuple[str, AgentCommand]:
        """The agent and command of a sealed AgentCommand the world must obey.

        Raises AuthError (or MessageError for a malformed payload) for anything
        else: unsigned, for another agent, no lease, not the holder, outside
        the lease. Counted in ``commands_accepted`` / ``commands_refused``.
        ``now``: the wall clock, when the caller read it already (a bundle).
        """
        agent = self._agent_of.get(key) or keys.parse_agent_key(self.realm, self.world, key)
        try:
            if self.verifier is None:
                raise AuthError("unauthenticated", "this world was started without --registry-key")
            if agent is None:
                raise AuthError("forbidden", f"{key} is not an agent's command key")
            if self.stopped:
                raise AuthError("forbidden", f"command to {agent} refused: {self.stopped}")
            try:
                envelope = decode(payload, (AuthEnvelope, MacCommand))
            except MessageError as exc:
                self.verifier.rejected += 1
                raise AuthError("unauthenticated", f"not an authenticated command: {exc}") from None
            if type(envelope) is MacCommand:
                command = self._check_mac(key, agent, envelope, time.time() if now is None else now)
                self.mac_accepted += 1
            else:
                assert isinstance(envelope, AuthEnvelope)  # the decoder allowed only these two
                command = self._check_signed(key, agent, envelope)
        except Exception:
            self.commands_refused += 1
            raise
        self.commands_accepted += 1
        return agent, command

    def _check_epoch(self, sent_at: float, lease_id: str) -> None:
        if sent_at < self.started_at:
            assert self.verifier is not None
            self.verifier.rejected += 1
            raise AuthError(
                "unauthenticated",
                f"command under lease {lease_id} was sealed before this world started",
            )

    def _check_signed(self, key: str, agent: str, envelope: AuthEnvelope) -> AgentCommand:
        """The command of an Ed25519 AuthEnvelope from the current lease holder; else AuthError."""
        assert self.verifier is not None
        self._check_epoch(envelope.sent_at, "(signed)")
        principal, command = self.verifier.open_envelope(key, envelope, AgentCommand)
        if command.agent != agent:
            raise AuthError("forbidden", f"command for {command.agent} sent on {key}")
        lease = self.lease_of(agent)
        now = time.time()
        if lease is None:
            raise AuthError("forbidden", f"{agent} has no lease: command dropped")
        if principal.session_id != lease.holder_session:
            raise AuthError("forbidden", f"{principal.user} does not hold {agent}'s lease")
        if not lease.start <= now <= lease.end:
            raise AuthError("forbidden", f"{principal.user}'s lease on {agent} is not in force")
        return command

    def _check_mac(self, key: str, agent: str, message: MacCommand, now: float) -> AgentCommand:
        """The command of a MacCommand, if it is the current MAC lease holder's; else AuthError.

        Order: the cheap refusals first, then the MAC (before decoding the body
        or touching the replay window, so nobody without K can move either).
        """
        assert self.verifier is not None
        with self._lock:  # one consistent look at both tables
            lease = self._leases.get(agent)
            mac = self._mac.get(agent)
        if lease is None:
            raise AuthError("forbidden", f"{agent} has no lease: command dropped")
        if lease.lease_id != message.lease_id:
            raise AuthError("forbidden", f"lease {message.lease_id} is not {agent}'s current lease")
        if mac is None or mac[0] != lease.lease_id:
            raise AuthError(
                "forbidden", f"lease {lease.lease_id} carries no key for this world: sign commands"
            )
        _, lease_key, window, on_own_key = mac
        seq, sent_at, body = message.seq, message.sent_at, message.body
        if self._agent_of.get(key) == agent:
            expected = on_own_key.tag(seq, sent_at, body)
        else:  # a key under another prefix that still names this agent: hash it in full
            expected = command_mac(lease_key, key, message.lease_id, seq, sent_at, body)
        if not mac_matches(expected, message.mac):
            self.verifier.rejected += 1
            raise AuthError("unauthenticated", f"command MAC does not match lease {lease.lease_id}")
        if not lease.start <= now <= lease.end:
            raise AuthError("forbidden", f"lease {lease.lease_id} on {agent} is not in force")
        self._check_epoch(sent_at, lease.lease_id)
        self.verifier.check_fresh(sent_at, lease.holder_user)
        with self._lock:
            fresh = window.accept(seq)
        if not fresh:
            self.verifier.rejected += 1
            raise AuthError("unauthenticated", f"replayed command under lease {lease.lease_id}")
        command = decode(body, AgentCommand)
        if command.agent != agent:
            raise AuthError("forbidden", f"command for {command.agent} sent on {key}")
        return command
