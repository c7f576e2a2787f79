"""A viewer that stops hands its lab sessions over: no room left, no logout, so the runs go
on; a robot its teacher had taken over is handed back to the student's controller first,
since nothing can drive it from the session that stopped.

Real router, registry, engine (with a service identity), runner (its sandbox) and the
agent context ``arena``; the viewer's side is its LiveConnector, as in the process.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL
from common.client.lab_address import LabAddress
from common.service import close_session
from tests.conftest import Procs, Router, needs_sandbox
from tests.kit.agentkit import (
    CTX,
    agent_user,
    start_agent_context,
    start_engine,
    start_runner,
)
from tests.kit.lab import PASSWORD, ProcessLab, make_lab
from tests.kit.waits import wait_for
from viewers.web.connector import LiveConnector

pytestmark = [pytest.mark.shared_router, needs_sandbox]

FORWARD = (Path(__file__).parent / "controllers" / "forward.py").read_bytes()


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab, identity=True)
    start_runner(lab)
    start_agent_context(lab, slot=120.0)
    return lab


@pytest.fixture
def connector(lab: ProcessLab) -> Iterator[LiveConnector]:
    session = lab.zsession()
    address = LabAddress("127.0.0.1", lab.router.port, lab.router.realm)
    connector = LiveConnector(session, address, lab.key_hex)
    yield connector
    connector.close()
    close_session(session)


def test_a_handed_over_teacher_gives_the_robot_back_and_the_run_goes_on(
    lab: ProcessLab, connector: LiveConnector
) -> None:
    address = LabAddress("127.0.0.1", lab.router.port, lab.router.realm)
    with agent_user(lab, "alice") as alice:
        rid = alice.queue("k1", "deploy", source=FORWARD, filename="forward.py").request_id
        assert alice.wait_status(rid, {"running"}, timeout=60), "alice's controller never ran"
        ida = connector.login(address, "ida", PASSWORD)
        ida.join(CTX)
        assert "taken over from alice" in ida.take_over(CTX, "k1", True)
        wait_for(lambda: alice.is_taken_by("k1", "ida"), 15, what="k1 taken over by ida")

        token = ida.resume_token
        assert token is not None
        ida.hand_over()  # the viewer holding ida's session stops

        wait_for(lambda: not alice.is_taken_by("k1", "ida"), 15, what="k1 handed back")
        said = [s.reason for s in alice.statuses(rid)]
        assert any("ida handed your robot back" in r for r in said), said
        assert alice.wait_status(rid, FINAL, timeout=1.0) is None  # alice's slot goes on
        # The next viewer logs ida's page in again by its saved login.
        again = connector.resume(address, token)
        assert again.user == "ida"
        again.logout()
        alice.cancel(rid)
