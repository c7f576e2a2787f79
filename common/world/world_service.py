"""What every world serves, simulated (the Sim2D engine) or real (the Khepera bridge).

A controller cannot tell the two apart because both declare exactly this
interface, here, once (ARGoS's control interface, Enki's world): frames,
sensor batches and sample bundles out, commands (alone or bundled) and leases
in, the arena's emergency stop, snapshot, edit and map queries.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import msgspec
import zenoh

from common import keys, qos
from common.auth import Verifier
from common.keys import AliveKind
from common.messages import (
    AgentCommand,
    CommandBundle,
    MacCommandBundle,
    Message,
    Revocation,
    RobotTypeInfo,
    RobotTypeReply,
    SampleBundle,
    WorldLayout,
    decode,
    encode,
)
from common.revocations import RevocationFeed
from common.service import Service
from common.world.leases import LeaseBook

if TYPE_CHECKING:  # the registry is handed in; only its type is needed here
    from common.robots.registry import Registry


def robot_types(reg: Registry) -> RobotTypeReply:
    """A world's answer to "which robot types are there": each with its origin and parts."""
    return RobotTypeReply(
        types=[
            RobotTypeInfo(
                name=name,
                origin=reg.describe_origin("wart.agents", name)[-256:],
                components=[(c.name, c.type) for c in spec.components],
            )
            for name, spec in sorted(reg.robots.items())
        ],
        component_types=sorted(reg.components),
    )


class WorldService(Service):
    """Base of the engine's and the bridge's services; subclasses implement the handlers."""

    kind = AliveKind.WORLD
    _frame_pub: Any
    _layout_pub: Any
    _batch_pub: Any
    _samples_pub: Any
    _revocations: RevocationFeed | None = None
    # Set by each world before declare_world_interface: who signs, and who may drive.
    verifier: Verifier | None
    leases: LeaseBook

    def declare_world_interface(self) -> None:
        """Declare the world's keys (call from on_start, before the service's own threads)."""
        realm, name = self.realm, self.ident
        self._frame_pub = self.track(self.session.declare_publisher(keys.world_frame(realm, name)))
        self._layout_pub = self.track(
            self.session.declare_publisher(
                keys.world_layout(realm, name), **qos.of(keys.world_layout)
            )
        )
        self._batch_pub = self.track(
            self.session.declare_publisher(keys.world_sensors(realm, name))
        )
        # Express: a sample bundle is what controllers react to; batching it with
        # the frame would only add latency.
        self._samples_pub = self.track(
            self.session.declare_publisher(keys.world_samples(realm, name), express=True)
        )
        self.subscribe(keys.agent_cmd_all(realm, name), self._on_command)
        self.subscribe(keys.world_commands(realm, name), self._on_command_bundle)
        self.subscribe(keys.agent_lease_all(realm, name), self._on_lease)
        self.subscribe(keys.world_estop(realm, name), self._on_stop)
        self.serve(keys.world_snapshot(realm, name), self._on_snapshot)
        self.serve(keys.world_edit(realm, name), self._on_edit)
        self.serve(keys.world_map(realm, name), self._on_map)
        self.serve(keys.world_robots(realm, name), self._on_robots)
        verifier = self.verifier
        if verifier is not None:
            # A kicked or logged-out user's sessions lose their leases here too, not
            # only in the context: the robot stops even if the context is down.
            self._revocations = RevocationFeed(
                self.session, realm, verifier.registry_key, verifier, self._on_revoked
            )

    def close_world_interface(self) -> None:
        """Stop following revocations (call from on_stop)."""
        if self._revocations is not None:
            self._revocations.close()

    def _on_revoked(self, rev: Revocation) -> None:
        for agent in self.leases.revoke_session(rev.session_id):
            self.log.info(
                "%s's lease on %s ended: session revoked (%s); robot stopped",
                rev.user,
                agent,
                rev.reason,
            )
            self.halt_agent(agent)

    def _on_stop(self, sample: zenoh.Sample) -> None:
        """The arena's emergency stop: every robot stops now and stays stopped until released."""
        stop = self.leases.accept_stop(str(sample.key_expr), sample.payload)
        if stop is None:
            return
        self.halt_all(stop.engaged)
        if stop.engaged:
            self.log.warning("%s: every robot stopped, commands refused", self.leases.stopped)
        else:
            self.log.warning("emergency stop released by %s", stop.by)

    def announce_layout(self, layout: int) -> None:
        """Say the world's rows changed (robots added, removed, come online or gone): an
        agent context that reads no frames refetches the snapshot on this."""
        self._layout_pub.put(encode(WorldLayout(world=self.ident, layout=layout)))

    def publish_sample_bundle(self, tick: int, samples: dict[str, bytes]) -> None:
        """Put ``samples`` (agent -> its encoded SensorSample) as one SampleBundle."""
        self._samples_pub.put(
            encode(
                SampleBundle(
                    world=self.ident,
                    tick=tick,
                    agents=list(samples),
                    samples=[msgspec.Raw(payload) for payload in samples.values()],
                )
            )
        )

    def _on_command(self, sample: zenoh.Sample) -> None:
        self._accept_command(str(sample.key_expr), sample.payload)

    def _on_command_bundle(self, sample: zenoh.Sample) -> None:
        """Each bundled command as if put on its agent's own key; one refusal spares the rest.

        Either kind of bundle: a CommandBundle (each item an AuthEnvelope or a
        MacCommand) or a MacCommandBundle (MACed items in arrays, a swarm's).
        """
        bundle = decode(sample.payload, (CommandBundle, MacCommandBundle))
        if type(bundle) is MacCommandBundle:
            count = len(bundle.agents)
            refused = self.leases.check_mac_bundle(bundle, self._obey)
        else:
            assert isinstance(bundle, CommandBundle)  # the decoder allowed only these two
            count = len(bundle.commands)
            refused = self.leases.check_bundle(bundle.commands, self._obey)
        if refused:
            self.dropped += len(refused)
            self.log.warning(
                "refused %d of %d bundled commands: %s",
                len(refused),
                count,
                "; ".join(refused[:3]),
            )

    # -- what each world does with them

    def _accept_command(self, key: str, payload: Any) -> None:
        """Check a sealed or MACed command put on ``key`` and obey it; AuthError if refused."""
        self._obey(*self.leases.check_command(key, payload))

    def _obey(self, agent: str, command: AgentCommand) -> None:
        """Carry out a command the lease book accepted (AuthError if this world cannot)."""
        raise NotImplementedError

    def _on_lease(self, sample: zenoh.Sample) -> None:
        raise NotImplementedError

    def halt_agent(self, agent: str) -> None:
        """Stop the agent's wheels now (its driver lost the right to drive it)."""
        raise NotImplementedError

    def halt_all(self, engaged: bool) -> None:
        """Emergency stop: every robot's wheels stop now, and none moves on its own until
        released (the engine's wander rule included)."""
        raise NotImplementedError

    def _on_snapshot(self, query: zenoh.Query) -> Message:
        raise NotImplementedError

    def _on_edit(self, query: zenoh.Query) -> Message:
        raise NotImplementedError

    def _on_map(self, query: zenoh.Query) -> Message:
        raise NotImplementedError

    def _on_robots(self, query: zenoh.Query) -> Message:
        raise NotImplementedError
