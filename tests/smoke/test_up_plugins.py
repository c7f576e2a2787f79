"""A plugin's context type hosted on request by `wart up` (issue 34, runtime module loading).

examples/plugins/wart-race installed with pip (as tests/integration/test_plugins.py
does), then a whole `wart up` lab: an instructor asks host "local" for a race,
its params checked against the plugin's schema (bad ones refused in words), the
race comes up (its liveliness token), is listed in the host's rooms with its
kind, and stops on request.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import pytest

from common.client.host_client import host_loads, host_room, stop_hosted
from common.client.lab_client import LabClient
from common.lab_errors import LabError
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.registry.accounts_db import RegistryDB
from tests.integration.test_plugins import race_plugin  # noqa: F401 - the fixture
from tests.kit.lab import UpLab

pytestmark = pytest.mark.timeout(400)
TEACHER, PASSWORD = "teacher", "a long test password"


@pytest.fixture(scope="module")
def teacher(
    tmp_path_factory: pytest.TempPathFactory,
    race_plugin: None,  # noqa: F811
) -> Iterator[LabClient]:
    realm = f"t{uuid.uuid4().hex[:10]}"
    lab = UpLab(realm=realm, state_dir=tmp_path_factory.mktemp("plugins") / "state").start()
    try:
        key = lab.wait_line("registry key", timeout=60).split(":", 1)[1].strip()
        lab.wait_line("hosting local", timeout=90)
        db = RegistryDB(lab.state_dir / "registry.db")
        try:
            db.add_user(TEACHER, ["instructor"], password=PASSWORD)
        finally:
            db.close()
        options = NetworkOptions(realm=realm, connect=(lab.endpoint,), registry_key=key)
        session = open_session(options, wait=10)
        client = LabClient(session, realm, key)
        try:
            client.login(TEACHER, PASSWORD)
            yield client
        finally:
            client.close()
            close_session(session)
    finally:
        code = lab.stop()
        assert code == 0, "\n".join(lab.lines)


def test_a_plugin_context_type_is_hosted_on_request_with_checked_params(
    teacher: LabClient,
) -> None:
    refused = [
        (
            "race",
            {"world": "arena", "start": "1,2,3,4", "laps": "0"},
            r"race: laps: must be at least 1, got 0",
        ),
        ("race", {"world": "arena"}, r"race: start: is required"),
        (
            "race",
            {"world": "arena", "start": "1,2,3,4", "colour": "red"},
            r"race: colour: not a parameter of this context type",
        ),
        ("tournament", {}, r"has no context type 'tournament' \(it has: chat, race\)"),
    ]
    for kind, params, why in refused:
        with pytest.raises(LabError, match=why):
            host_room(teacher, "race0", kind=kind, params=params)

    info = host_room(
        teacher,
        "race1",
        "Sprint",
        kind="race",
        params={"world": "arena", "start": "400,550,400,50", "laps": "2"},
    )
    assert (info.name, info.kind, info.state, info.owner) == ("race1", "race", "running", TEACHER)
    local = next(load for load in host_loads(teacher.z, teacher.realm) if load.host == "local")
    assert [(r.name, r.kind) for r in local.rooms] == [("race1", "race")]
    assert "stopped" in stop_hosted(teacher, "race1", "room")
