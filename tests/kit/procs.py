"""The tests' and benchmarks' ``wart`` processes: started, each with its output in a file,
and stopped; a real router on a free 127.0.0.1 port.

Where it can, a process is forked from the kit's fork server (tests/kit/forkserver.py:
the interpreter and the lab's modules loaded once), else started as ``python -m
services.cli``; either way with the test environment (:func:`wart_env`: multicast
scouting off, none of the developer's own lab). The labs built of them are
tests/kit/lab.py's.
"""

from __future__ import annotations

import atexit
import os
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab import wiring
from services.lab.supervisor import AliveWatch
from tests.kit import forkserver
from tests.kit.forkserver import ForkedProcess, ForkServer, Running
from tests.kit.waits import wait_for

REPO = Path(__file__).resolve().parents[2]
# Where this process's `wart` processes are forked from (tests/kit/forkserver.py).
FORK_SERVER = ForkServer(REPO)
atexit.register(FORK_SERVER.stop)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wart_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONUNBUFFERED"] = "1"
    env["WART_NO_MULTICAST"] = "1"
    # Nothing of the developer's own lab: its router, realm or credentials.
    for name in ("WART_CONNECT", "WART_REALM", "WART_PASSWORD", "WART_REGISTRY_KEY"):
        env.pop(name, None)
    if extra:
        env.update(extra)
    return env


# --- processes -----------------------------------------------------------------------


def wart(
    *args: str, timeout: float = 120.0, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``wart ARGS`` as a person runs it, from the repository, output captured; ``env``
    adds to the test environment (see wart_env)."""
    if forkserver.enabled():
        return _forked_wart(list(args), timeout, wart_env(env))
    return subprocess.run(
        [sys.executable, "-m", "services.cli", *args],
        cwd=REPO,
        env=wart_env(env),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _fork(args: Sequence[str], env: dict[str, str], stdout: int, stderr: int) -> ForkedProcess:
    """``wart ARGS`` forked from the kit's server, in the repository, reading nothing."""
    with open(os.devnull, "rb") as nothing:
        return FORK_SERVER.spawn(
            args, cwd=REPO, env=env, stdin=nothing.fileno(), stdout=stdout, stderr=stderr
        )


def _forked_wart(
    args: list[str], timeout: float, env: dict[str, str]
) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "services.cli", *args]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = _fork(args, env, out.fileno(), err.fileno())

        def read(stream: IO[bytes]) -> str:
            stream.seek(0)
            return stream.read().decode(errors="replace")

        try:
            code = proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
            raise subprocess.TimeoutExpired(command, timeout, read(out), read(err)) from None
        return subprocess.CompletedProcess(command, code, read(out), read(err))


@dataclass
class Proc:
    """A ``wart`` subprocess started by a test, with its output in a file."""

    name: str
    popen: Running  # a subprocess.Popen, or a ForkedProcess from the kit's fork server
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
    """Starts ``wart`` subprocesses and stops them all at teardown.

    ``env``: variables every process gets (a benchmark quiets the logs).
    """

    tmp: Path
    started: list[Proc] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)

    def start(self, name: str, args: Sequence[str], env: dict[str, str] | None = None) -> Proc:
        log_path = self.tmp / f"{name}.log"
        out = open(log_path, "wb")  # noqa: SIM115 - the child writes to it for its lifetime
        environment = wart_env({**self.env, **(env or {})})
        popen: Running
        if forkserver.enabled():
            popen = _fork(args, environment, out.fileno(), out.fileno())
        else:
            popen = subprocess.Popen(
                [sys.executable, "-m", "services.cli", *args],
                cwd=REPO,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=environment,
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

    def in_realm(self, realm: str) -> Router:
        """The same router process, for clients and services of another realm."""
        return Router(realm=realm, port=self.port, proc=self.proc)


def wait_alive(options: NetworkOptions, key: str, proc: Proc, timeout: float = 30.0) -> None:
    """Return once ``key``'s liveliness token is seen; fail with the process's output if it
    exits or the token does not come in time (never a fixed sleep)."""
    session = open_session(options, wait=20.0)
    try:
        watch = AliveWatch(session, key)
        ok = watch.wait(key, timeout, lambda: proc.popen.poll() is not None)
        watch.close()
    finally:
        close_session(session)
    assert ok, f"{proc.name} did not come up ({key}):\n{proc.output()}"


def start_router(
    procs: Procs,
    realm: str,
    name: str = "test-router",
    *,
    port: int | None = None,
    connect: Sequence[str] = (),
    log_name: str = "router",
) -> Router:
    """A real ``wart router`` on a free 127.0.0.1 port (or ``port``, to restart one where
    it was), multicast scouting off; ``connect``: routers it meshes with (a second host)."""
    port = port or free_port()
    spec = wiring.router_spec(realm, name, [f"tcp/127.0.0.1:{port}"], connect=connect)
    proc = procs.start(log_name, [*spec.argv, "--no-multicast-scouting"])
    router = Router(realm=realm, port=port, proc=proc)
    assert spec.alive_key is not None
    # Its port first, polled often: a session opened before the router listens backs off
    # for up to 2 s, which every test starting a router paid for nothing.
    wait_for(
        lambda: proc.popen.poll() is not None or _accepts(port),
        20.0,
        f"the router to listen on port {port}",
    )
    wait_alive(router.options(), spec.alive_key, proc, timeout=20.0)
    return router


def _accepts(port: int) -> bool:
    with socket.socket() as sock:
        sock.settimeout(1.0)
        return sock.connect_ex(("127.0.0.1", port)) == 0
