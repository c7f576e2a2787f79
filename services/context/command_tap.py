"""The commands of a recorded slot, checked as the world checks them before they are written.

A command goes into a run's recording only if the world would have obeyed it: the
lease holder's, signed by its session or MACed with the run's lease key (over the
agent's own key expression), for that agent, sent within the slot; a taken-over
run's, the teacher's lease. A refused one is counted in the run, not recorded. Alone
(``world/<w>/agent/<a>/cmd``) or bundled (``world/<w>/cmds``: a CommandBundle, or a
swarm's MacCommandBundle). The recorder's writer thread calls this part.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from common import keys
from common.auth import AuthError
from common.messages import (
    MAC_ITEM_BYTES,
    MAC_ITEM_COUNTERS,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    AgentCommand,
    AuthEnvelope,
    CommandBundle,
    MacCommand,
    MacCommandBundle,
    MessageError,
    decode,
)
from common.recording import schema as s
from common.world.leasemac import MAC_BYTES, command_mac, item_mac, mac_matches

if TYPE_CHECKING:
    from services.context.recorder import SlotRecorder, _Run


class CommandTap:
    def __init__(self, recorder: SlotRecorder) -> None:
        self.recorder = recorder

    def bundle(self, payload: bytes, t: float) -> None:
        try:
            bundle = decode(payload, (CommandBundle, MacCommandBundle))
        except MessageError:
            return
        if isinstance(bundle, MacCommandBundle):
            self._mac_items(bundle, t)
            return
        assert isinstance(bundle, CommandBundle)  # the decoder allowed only these two
        for item in bundle.commands:
            if self.recorder.is_recording(item.agent):
                key = keys.agent_cmd(self.recorder.realm, self.recorder.world, item.agent)
                self.command(key, item.agent, item.payload, t)

    def _mac_items(self, bundle: MacCommandBundle, t: float) -> None:
        """A swarm's MacCommandBundle: each item of a recorded agent, if MACed with its run's
        lease key (over the agent's own key expression) and sent within the run's slot."""
        n = len(bundle.agents)
        if len(bundle.items) != n * MAC_ITEM_BYTES or len(bundle.macs) != n * MAC_BYTES:
            return  # the world refuses it whole, too
        for i, agent in enumerate(bundle.agents):
            rec = self.recorder.active_run(agent)
            if rec is None:
                continue
            run = rec.run.taken or rec.run  # taken over: the teacher's lease is in force
            if not run.lease_key:  # not a MAC lease: a keyless BLAKE2b proves nothing
                rec.refused += 1
                continue
            record = bundle.items[i * MAC_ITEM_BYTES : (i + 1) * MAC_ITEM_BYTES]
            key = keys.agent_cmd(self.recorder.realm, self.recorder.world, agent)
            expected = item_mac(run.lease_key, key, run.lease_id, record)
            _seq, sent_at, flags, left, right, a, b = MAC_ITEM_STRUCT.unpack(record)
            if (
                not mac_matches(expected, bundle.macs[i * MAC_BYTES : (i + 1) * MAC_BYTES])
                or not run.start - 1.0 <= sent_at <= run.end + 1.0
                or flags & ~(MAC_ITEM_SPEEDS | MAC_ITEM_COUNTERS)
            ):
                rec.refused += 1
                continue
            command = AgentCommand(
                agent=agent,
                speeds=(left, right) if flags & MAC_ITEM_SPEEDS else None,
                counters=(a, b) if flags & MAC_ITEM_COUNTERS else None,
            )
            driver = rec.driver if run is rec.run else run.job.user
            self._write_command(rec, agent, driver, "mac", command, t)

    def _write_command(
        self, rec: _Run, agent: str, sender: str, auth: str, command: AgentCommand, t: float
    ) -> None:
        leds: list[bool | int] | None = None if command.leds is None else [*command.leds]
        record = s.CommandRecord(
            agent=agent,
            sender=sender,
            auth=auth,
            speeds=command.speeds,
            counters=command.counters,
            leds=leds,
            arm=command.arm,
            grip=command.grip,
        )
        rec.writer.write(s.commands_topic(agent), record, t)

    def command(self, key: str, agent: str, payload: bytes, t: float) -> None:
        rec = self.recorder.active_run(agent)
        if rec is None:
            return
        run = rec.run.taken or rec.run  # taken over: the teacher's lease is in force
        try:
            envelope = decode(payload, (AuthEnvelope, MacCommand))
            if isinstance(envelope, MacCommand):
                expected = command_mac(
                    run.lease_key,
                    key,
                    envelope.lease_id,
                    envelope.seq,
                    envelope.sent_at,
                    envelope.body,
                )
                if (
                    not run.lease_key  # not a MAC lease: a keyless BLAKE2b proves nothing
                    or envelope.lease_id != run.lease_id
                    or not mac_matches(expected, envelope.mac)
                ):
                    raise AuthError("forbidden", "not MACed with this run's lease key")
                command, sender, auth, sent_at = (
                    decode(envelope.body, AgentCommand),
                    rec.driver if run is rec.run else run.job.user,
                    "mac",
                    envelope.sent_at,
                )
            else:
                assert isinstance(envelope, AuthEnvelope)
                verifier = self.recorder.verifier
                principal, command = verifier.open_envelope(key, envelope, AgentCommand)
                if principal.session_id != run.holder_session:
                    raise AuthError("forbidden", f"{principal.user} does not hold the lease")
                sender, auth, sent_at = principal.user, "signed", envelope.sent_at
            if command.agent != agent or not run.start - 1.0 <= sent_at <= run.end + 1.0:
                raise AuthError("forbidden", "another agent's, or outside the slot")
        except (AuthError, MessageError):
            rec.refused += 1
            return
        self._write_command(rec, agent, sender, auth, command, t)
