"""Shared fixtures: a real Zenoh router on a free port, clients, and process helpers.

Every process a test starts runs on 127.0.0.1 with multicast scouting off, and
is stopped (then killed, if it must be) when the test ends.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from common import keys
from common.keys import AliveKind
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab.supervisor import AliveWatch

REPO = Path(__file__).resolve().parent.parent
ARTIFACTS = REPO / "test-artifacts"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # Under xdist (./dev test), the browser tests run one at a time on one
    # worker: each drives a Chromium rendering WebGL in software, and two at
    # once on two cores made each page slow for nothing. The other tests,
    # which mostly wait on their processes, share the other workers.
    for item in items:
        if "browser" in item.keywords or item.path.parent.name == "browser":
            item.add_marker(pytest.mark.xdist_group("browser"))


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wart_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONUNBUFFERED"] = "1"
    env["WART_NO_MULTICAST"] = "1"
    env.pop("WART_CONNECT", None)
    env.pop("WART_REALM", None)
    if extra:
        env.update(extra)
    return env


@dataclass
class Proc:
    """A ``wart`` subprocess started by a test, with its output in a file."""

    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path

    def output(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def stop(self, timeout: float = 10.0) -> int | None:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGTERM)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5)
        return self.popen.returncode

    def kill9(self) -> None:
        self.popen.kill()
        self.popen.wait(5)


@dataclass
class Procs:
    """Starts ``wart`` subprocesses and stops them all at teardown."""

    tmp: Path
    started: list[Proc] = field(default_factory=list)

    def start(self, name: str, args: Sequence[str], env: dict[str, str] | None = None) -> Proc:
        log_path = self.tmp / f"{name}.log"
        out = open(log_path, "wb")  # noqa: SIM115 - the child writes to it for its lifetime
        popen = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *args],
            cwd=REPO,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            env=wart_env(env),
            start_new_session=True,
        )
        out.close()
        proc = Proc(name, popen, log_path)
        self.started.append(proc)
        return proc

    def stop_all(self) -> None:
        for proc in reversed(self.started):
            proc.stop()


@dataclass
class Router:
    realm: str
    port: int
    proc: Proc

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def options(self, **changes: object) -> NetworkOptions:
        """Network options for a client of this router (what services get in tests)."""
        base = NetworkOptions(realm=self.realm, mode="client", connect=(self.endpoint,))
        return base.with_(**changes) if changes else base

    def net_args(self) -> list[str]:
        return self.options().as_args()


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    manager = Procs(tmp_path)
    yield manager
    manager.stop_all()


@pytest.fixture
def realm() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


def wait_for(
    condition: Callable[[], object], timeout: float = 10.0, what: str = "condition"
) -> object:
    """Poll ``condition`` until it returns something truthy; fail with ``what`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.02)


@pytest.fixture
def router(procs: Procs, realm: str) -> Iterator[Router]:
    """A real ``wart router`` process on a free 127.0.0.1 port, multicast scouting off."""
    port = free_port()
    proc = procs.start(
        "router",
        [
            "router",
            "--realm",
            realm,
            "--name",
            "test-router",
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--no-multicast-scouting",
        ],
    )
    r = Router(realm=realm, port=port, proc=proc)
    session = open_session(r.options(), wait=20.0)
    try:
        watch = AliveWatch(session, keys.alive(realm, AliveKind.ROUTER, "test-router"))
        if not watch.wait(keys.alive(realm, AliveKind.ROUTER, "test-router"), 20.0):
            raise AssertionError(f"router did not come up:\n{proc.output()}")
        watch.close()
    finally:
        close_session(session)
    yield r
    proc.stop()


@pytest.fixture
def zsession(router: Router) -> Iterator[zenoh.Session]:
    """A Zenoh client session connected to the test router."""
    session = open_session(router.options(), wait=10.0)
    yield session
    close_session(session)


@pytest.fixture
def alive_watch(zsession: zenoh.Session, router: Router) -> Iterator[AliveWatch]:
    watch = AliveWatch(zsession, keys.alive_all(router.realm))
    yield watch
    watch.close()
