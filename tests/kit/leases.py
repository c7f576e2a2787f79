"""Leases as an agent context grants them, for tests and benchmarks of the world's side."""

from __future__ import annotations

import msgspec

from common import keys
from common.auth import Session
from common.messages import Lease
from common.world.leasemac import seal_key
from common.world.leases import LeaseBook
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
