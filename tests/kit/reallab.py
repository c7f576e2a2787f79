"""One real lab per test module for browser tests: router, registry, lobby room, engine, viewer.

Everything but the viewer is a real ``wart`` process on 127.0.0.1 (multicast
scouting off), started by tests/kit/lab.py; the viewer runs in the test process over
a real Zenoh session with :class:`~viewers.web.live.LiveConnector`, so tests can read its state
(views, frames) as well as the page. With ``agents`` the lab also runs a
runner (sandboxed uploads) and the agent context ``arena`` on the world
(owner ida, short slots), and the engine logs in as a service account so
leases carry per-lease MAC keys, as under ``wart up``.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import zenoh

from common import keys
from common.auth import issue_session
from common.client.lab_address import LabAddress
from common.client.lab_client import LabClient
from common.messages import AgentCommand, Lease
from common.service import close_session, open_session
from services.lab.real_arenas import bridge_specs
from tests.kit.agentkit import (
    CTX,
    start_agent_context,
    start_engine,
    start_runner,
    together,
)
from tests.kit.lab import PASSWORD, ProcessLab, make_lab
from tests.kit.procs import Procs, Router, free_port, start_router
from viewers.web.app import WebViewer
from viewers.web.connector import LiveConnector

WORLD = "w1"


@dataclass
class RealLab:
    lab: ProcessLab
    router: Router
    address: LabAddress
    session: zenoh.Session
    connector: LiveConnector
    viewer: WebViewer

    @property
    def url(self) -> str:
        return self.address.url()

    @contextmanager
    def driving(
        self, agent: str = "k0", speeds: tuple[int, int] = (8, 3), world: str = WORLD
    ) -> Iterator[None]:
        """Drive ``agent`` the real way while the block runs.

        alice logs in with her password; a lease for her session is published
        with a session that has the ``lease`` permission (what an agent
        context does; issued here with the registry's identity); her sealed
        commands then pass the engine's lease check.
        """
        realm = self.router.realm
        with self.lab.client("alice") as alice:
            session = alice.session
            assert session is not None
            grantor = issue_session(self.lab.identity, realm, "ctx-test", ["lease"])
            now = time.time()
            lease = Lease(
                lease_id=f"L{uuid.uuid4().hex[:8]}",
                world=world,
                agent=agent,
                holder_user="alice",
                holder_session=session.session_id,
                start=now - 1,
                end=now + 120,
            )
            lease_key = keys.agent_lease(realm, world, agent)
            z = alice.z
            z.put(lease_key, grantor.seal(lease_key, lease))
            stop = threading.Event()
            cmd_key = keys.agent_cmd(realm, world, agent)

            def loop() -> None:
                command = AgentCommand(agent=agent, speeds=speeds)
                while not stop.is_set():
                    z.put(cmd_key, session.seal(cmd_key, command))
                    stop.wait(0.05)  # a controller's period

            thread = threading.Thread(target=loop, daemon=True)
            thread.start()
            try:
                yield
            finally:
                stop.set()
                thread.join(2)


@contextmanager
def real_lab(
    tmp: Path,
    map_name: str = "foraging",
    *,
    agents: bool = False,
    slot: float = 4.0,
    wander: bool = False,
    real_arena: str | None = None,
) -> Iterator[RealLab]:
    """``real_arena``: also a real world of that name, an emulated Khepera (slipping, on
    maps/empty.json) behind a bridge, and a synthetic camera over it (as `wart up` runs)."""
    procs = Procs(tmp)
    realm = f"t{uuid.uuid4().hex[:10]}"
    try:
        router = start_router(procs, realm)
        lab = make_lab(router, procs, tmp)
        lab.start_registry()
        lab.start_room("lobby")
        if agents:
            together(lambda: start_engine(lab, map_name, identity=True), lambda: start_runner(lab))
            start_agent_context(lab, slot=slot)
        else:
            lab.start_engine(map_name, world=WORLD, extra=["--wander"] if wander else [])
        if real_arena:
            for spec in bridge_specs(lab.wiring(), real_arena, [], emulate="empty"):
                lab.start(spec)
        session = open_session(router.options(), wait=10.0)
        address = LabAddress("127.0.0.1", router.port, realm)
        connector = LiveConnector(session, address, lab.key_hex, data_dir=tmp / "viewer")
        viewer = WebViewer(
            connector, port=free_port(), default_address=address, data_dir=tmp / "viewer"
        )
        try:
            yield RealLab(lab, router, address, session, connector, viewer)
        finally:
            viewer.stop()
            connector.close()
            close_session(session)
    finally:
        procs.stop_all()


__all__ = ["CTX", "PASSWORD", "WORLD", "LabClient", "RealLab", "real_lab"]
