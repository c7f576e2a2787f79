"""``wart up`` hosts chat rooms and arenas on request (host "local").

Through common/client/host_client.py.

One lab (a real ``wart up`` subprocess: router, registry, services) for the
module; an instructor (``host`` permission) and a student are added to its
registry DB while it runs (logins read the DB).
"""

from __future__ import annotations

import subprocess
import uuid
from collections.abc import Callable, Iterator

import psutil
import pytest
import zenoh

from common.client.host_client import NameTaken, host_arena, host_loads, host_room, stop_hosted
from common.client.lab_client import LabClient
from common.lab_errors import NotAllowed, NotFound
from common.messages import ContextInfo
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.registry.accounts_db import RegistryDB
from tests.conftest import wait_for
from tests.kit.lab import UpLab
from tests.kit.procs import wart as lab_wart

# One worker starts the module's lab once (split between workers, each started its own).
pytestmark = pytest.mark.one_worker

TEACHER, STUDENT, PASSWORD = "teacher", "pupil", "a long test password"


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[UpLab, str]]:
    realm = f"t{uuid.uuid4().hex[:10]}"
    lab = UpLab(realm=realm, state_dir=tmp_path_factory.mktemp("hosting") / "state").start()
    try:
        line = lab.wait_line("registry key", timeout=60)
        key = line.split(":", 1)[1].strip()
        lab.wait_line("hosting local", timeout=90)
        db = RegistryDB(lab.state_dir / "registry.db")
        try:
            db.add_user(TEACHER, ["instructor"], password=PASSWORD)
            db.add_user(STUDENT, ["student"], password=PASSWORD)
        finally:
            db.close()
        yield lab, key
    finally:
        code = lab.stop()
        assert code == 0, "\n".join(lab.lines)


@pytest.fixture
def client_of(lab: tuple[UpLab, str]) -> Iterator[Callable[[str], LabClient]]:
    the_lab, key = lab
    opened: list[tuple[LabClient, zenoh.Session]] = []

    def make(user: str) -> LabClient:
        session = open_session(
            NetworkOptions(realm=the_lab.realm, connect=(the_lab.endpoint,), registry_key=key),
            wait=10,
        )
        client = LabClient(session, the_lab.realm, key)
        opened.append((client, session))
        client.login(user, PASSWORD)
        return client

    yield make
    for client, session in opened:
        client.close()
        close_session(session)


def _context(client: LabClient, name: str) -> ContextInfo | None:
    return next((c for c in client.directory().contexts if c.ctx == name), None)


def test_instructor_hosts_a_room_and_an_arena_everyone_sees_them_then_stops_them(
    client_of: Callable[[str], LabClient],
) -> None:
    teacher = client_of(TEACHER)
    student = client_of(STUDENT)

    room = host_room(teacher, "reading", "Reading group")
    assert (room.name, room.host, room.owner) == ("reading", "local", TEACHER)
    assert room.state == "running"
    arena = host_arena(teacher, "arena7", "foraging", robots=3)
    assert (arena.world, arena.host, arena.owner, arena.robots) == ("arena7", "local", TEACHER, 3)

    # In the registry's directory for everyone (it re-asks contexts every ~2 s).
    shown = wait_for(
        lambda: (
            (_context(student, "reading"), _context(student, "arena7"))
            if _context(student, "reading") and _context(student, "arena7")
            else None
        ),
        15,
        "the hosted room and arena in the student's directory",
    )
    room_info, arena_info = shown  # type: ignore[misc]
    assert (room_info.kind, room_info.owner, room_info.title) == ("chat", TEACHER, "Reading group")
    assert (arena_info.kind, arena_info.owner) == ("agent", TEACHER)
    # The student can join and chat in the new room.
    joined = student.join("reading", lambda _event: None)
    assert joined.owner == TEACHER

    # The host's load lists both with their processes.
    (local,) = host_loads(teacher.z, teacher.realm)
    assert [r.name for r in local.rooms] == ["reading"]
    (listed,) = [a for a in local.arenas if a.world == "arena7"]
    assert len(listed.pids) == 2  # the engine and its agent context
    student.leave("reading")

    assert "stopped" in stop_hosted(teacher, "reading")
    assert "stopped" in stop_hosted(teacher, "arena7", "arena")
    wait_for(
        lambda: _context(student, "reading") is None and _context(student, "arena7") is None,
        15,
        "the stopped room and arena gone from the directory",
    )
    for pid in listed.pids:
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    (local,) = host_loads(teacher.z, teacher.realm)
    assert local.rooms == [] and all(a.world != "arena7" for a in local.arenas)


def test_refusals_say_why(client_of: Callable[[str], LabClient], lab: tuple[UpLab, str]) -> None:
    teacher = client_of(TEACHER)
    student = client_of(STUDENT)
    with pytest.raises(NotAllowed, match="does not have the 'host' permission"):
        host_room(student, "mine", "My room")
    with pytest.raises(NotAllowed, match="does not have the 'host' permission"):
        host_arena(student, "mine", "foraging")
    with pytest.raises(NotFound, match="map 'atlantis' not found"):
        host_arena(teacher, "sunk", "atlantis")
    with pytest.raises(NameTaken, match="lobby is taken"):
        host_room(teacher, "lobby", "Another lobby")
    with pytest.raises(NameTaken, match="arena1 is taken"):
        host_arena(teacher, "arena1", "maze")
    with pytest.raises(NotFound, match="no host runs a chat room named nothing"):
        stop_hosted(teacher, "nothing", "room")
    assert _context(teacher, "mine") is None and _context(teacher, "sunk") is None
    # Host "local" runs inside `wart up`: its refusals go to its own log file, like every
    # service's, and not to the operator's terminal.
    the_lab = lab[0]
    log = the_lab.state_dir / "logs" / "host-local.log"
    refused = "does not have the 'host' permission"
    wait_for(lambda: refused in log.read_text(), 10, "the refusal in host-local.log")
    assert not any(refused in line for line in the_lab.lines), "\n".join(the_lab.lines)


def test_wart_room_in_a_terminal(lab: tuple[UpLab, str]) -> None:
    the_lab, key = lab
    flags = ["--realm", the_lab.realm, "--connect", the_lab.endpoint, "--registry-key", key]

    def wart(*args: str) -> subprocess.CompletedProcess[str]:
        return lab_wart(*args, timeout=60.0, env={"WART_PASSWORD": PASSWORD})

    made = wart("room", *flags, "new", "--user", TEACHER, "club", "--title", "Robot club")
    assert made.returncode == 0, made.stderr
    assert "chat room club (Robot club) is open on local" in made.stdout
    refused = wart("room", *flags, "stop", "--user", STUDENT, "club")
    assert refused.returncode == 1
    assert "does not have the 'host' permission" in refused.stderr
    stopped = wart("room", *flags, "stop", "--user", TEACHER, "club")
    assert stopped.returncode == 0, stopped.stderr
    assert "chat room club stopped on local" in stopped.stdout
