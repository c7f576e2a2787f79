"""Leases as an agent context grants them, for tests and benchmarks of the world's side."""

from __future__ import annotations

import time
from collections.abc import Sequence

import msgspec

from common import keys
from common.auth import RegistryIdentity, Session, Verifier, issue_session
from common.messages import Lease
from common.world.leasemac import WorldBoxKeys, new_lease_key, seal_key
from common.world.leases import LeaseBook
from common.world.remote_robot import WorldChannel, ZenohRobotLink
from tests.kit.fakezenoh import FakeSample, FakeSession


def holder_lease(
    holder: Session, *, lease_id: str, world_name: str, agent: str, start: float, end: float
) -> Lease:
    """``holder``'s lease of ``agent`` in ``world_name`` from ``start`` to ``end`` (epoch s),
    with no MAC key: its commands are signed envelopes."""
    return Lease(
        lease_id=lease_id,
        world=world_name,
        agent=agent,
        holder_user=holder.user,
        holder_session=holder.session_id,
        start=start,
        end=end,
    )


def mac_lease(
    k: bytes,
    holder: Session,
    world: Session,
    *,
    lease_id: str,
    world_name: str,
    agent: str,
    start: float,
    end: float,
) -> Lease:
    """``holder``'s lease of ``agent`` in ``world_name`` from ``start`` to ``end`` (epoch s),
    its MAC key ``k`` sealed for the holder and for the world (``world``: its login)."""
    return msgspec.structs.replace(
        holder_lease(
            holder, lease_id=lease_id, world_name=world_name, agent=agent, start=start, end=end
        ),
        holder_key=seal_key(k, holder.keys.box_public_key),
        world_key=seal_key(k, world.keys.box_public_key),
        world_box=world.keys.box_public_key,
    )


def grant_on(zs: FakeSession, book: LeaseBook, context: Session, realm: str, lease: Lease) -> None:
    """``lease`` as its agent context publishes it: sealed by ``context``, accepted by the
    world's ``book``, and handed to the link of its agent subscribed on ``zs``."""
    key = keys.agent_lease(realm, lease.world, lease.agent)
    sealed = context.seal(key, lease)
    book.accept_lease(key, sealed)
    zs.callbacks[key](FakeSample(sealed))


def mac_leased_swarm(
    identity: RegistryIdentity,
    holder: Session,
    realm: str,
    world_name: str,
    agents: Sequence[str],
    leased: Sequence[str],
    lease_s: float,
) -> tuple[FakeSession, WorldChannel, list[ZenohRobotLink], LeaseBook]:
    """``holder``'s links of ``agents`` on one WorldChannel (a FakeSession's); those of
    ``leased`` hold a MAC lease for ``lease_s`` that the world's LeaseBook has too."""
    world = issue_session(identity, realm, f"engine-{world_name}", ["world"])
    context = issue_session(identity, realm, "ctx", ["lease"])
    book = LeaseBook(
        realm, world_name, Verifier(identity.verify_key, realm), WorldBoxKeys(lambda: world)
    )
    zs = FakeSession()
    channel = WorldChannel(zs, realm, world_name)  # type: ignore[arg-type]
    links = [
        ZenohRobotLink(
            zs,  # type: ignore[arg-type]
            realm,
            world_name,
            agent,
            lambda: holder,
            keepalive=3600.0,
            verifier=Verifier(identity.verify_key, realm),  # the holder's own
            channel=channel,
        )
        for agent in agents
    ]
    now = time.time()
    for i, agent in enumerate(leased):
        lease = mac_lease(
            new_lease_key(),
            holder,
            world,
            lease_id=f"L{i}",
            world_name=world_name,
            agent=agent,
            start=now - 1,
            end=now + lease_s,
        )
        grant_on(zs, book, context, realm, lease)  # the link opens its copy of the key
    return zs, channel, links, book
