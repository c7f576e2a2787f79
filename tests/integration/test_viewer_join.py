"""The viewer joins an arena as an arena even before the lab's directory lists it.

On a busy machine the registry may not yet have seen an agent context come up
when a student clicks to join it; the viewer used to take any context it could
not find in the directory for a chat room, and the student got the arena's chat
and nothing else (no robots, no editor, no word of why), as a browser test saw
under load.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from common.client.lab_address import LabAddress
from common.service import close_session
from tests.conftest import Procs, Router
from tests.kit.agentkit import CTX, WORLD, start_agent_context, start_engine
from tests.kit.lab import PASSWORD, ProcessLab, make_lab
from viewers.web.adapters import ContextSummary
from viewers.web.connector import LiveConnector

pytestmark = pytest.mark.shared_router


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab)
    start_agent_context(lab)
    return lab


@pytest.mark.parametrize("listed", ["not at all", "as unknown"])
def test_an_arena_the_directory_does_not_know_yet_is_joined_as_an_arena(
    lab: ProcessLab, monkeypatch: pytest.MonkeyPatch, listed: str
) -> None:
    session = lab.zsession()
    address = LabAddress("127.0.0.1", lab.router.port, lab.router.realm)
    connector = LiveConnector(session, address, lab.key_hex)
    try:
        connection = connector.login(address, "bob", PASSWORD)
        # The registry has not seen the context come up (nothing listed), or the context
        # did not answer its question in time (listed with the kind "unknown").
        kinds = {} if listed == "not at all" else {CTX: ContextSummary(CTX, "unknown", "", "", 0)}
        monkeypatch.setattr(connection, "_kinds", kinds)
        monkeypatch.setattr(connection, "directory", lambda: None)
        joined = connection.join(CTX)
        assert (joined.kind, joined.world) == ("agent", WORLD)
        connection.logout()
    finally:
        connector.close()
        close_session(session)
