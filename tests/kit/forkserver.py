"""A fork server for the kit's ``wart`` processes: each is forked from one process that has
already imported what every service imports, instead of a new interpreter importing it all.

Why: a service's start is mostly imports (numpy, zenoh, msgspec, nacl and the lab's own
modules: 0.4 to 0.7 s of a core each), and the suite starts hundreds of routers,
registries, engines and command-line calls. On a two-core CI machine that CPU is the
suite's wall time. Each forked process is still its own process, with its own Zenoh
session, command line arguments, environment, working directory, session id and output
file: what runs is ``services.cli`` exactly as ``python -m services.cli`` runs it.

The server (``python -m tests.kit.forkserver SOCKET``) is single-threaded when it forks
(it imports nothing that starts a thread and never opens a session). A client sends the
request with the three standard streams as file descriptors (SCM_RIGHTS); the server
answers the child's pid, and later its exit code and CPU seconds on the same connection.
When the process that started the server goes away (a test run killed outright), the
server stops every process it forked: no lab is left running after its test.

The test suite turns it on (``WART_TEST_FORK=1``, set by tests/conftest.py; ``=0`` there
starts every process with a fresh interpreter). Benchmarks keep fresh interpreters: their
figures (a service's start, its memory) are those of a real start.
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

ENABLED_ENV = "WART_TEST_FORK"
# What every service imports, loaded once in the server; a module that fails to import
# is left to the child (which then reports it as it would).
PRELOAD = (
    "numpy",
    "zenoh",
    "msgspec",
    "nacl.public",
    "nacl.signing",
    "nacl.pwhash",
    "pymunk",
    "common.messages",
    "common.service",
    "common.client.lab_client",
    "services.cli",
    "services.router.main",
    "services.registry.main",
    "services.registry.service",
    "services.context.main",
    "services.engine.main",
    "services.runner.main",
)
STOP_GRACE_S = 5.0  # SIGTERM, then this long, then SIGKILL (the server's own stop)


# --- the server ----------------------------------------------------------------------


class _Child:
    """What the server's forked child runs: the request, at the interpreter's top level
    (so exit, atexit and uncaught errors behave as in ``python -m services.cli``)."""

    def __init__(self, request: dict[str, object], fds: Sequence[int], env_set: dict[str, str]):
        self.request = request
        self.fds = fds
        self.env_set = env_set

    def run(self) -> None:
        os.setsid()
        for target, fd in enumerate(self.fds):
            os.dup2(fd, target)
        for fd in self.fds:
            if fd > 2:
                os.close(fd)
        for sig in (signal.SIGCHLD, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        os.chdir(str(self.request["cwd"]))
        env = dict(self.request["env"])  # type: ignore[call-overload]
        # What a preloaded module put in the environment at import (it will not run again).
        for name, value in self.env_set.items():
            env.setdefault(name, value)
        os.environ.clear()
        os.environ.update(env)
        _path_as_at_start(str(self.request["cwd"]), env.get("PYTHONPATH", ""))
        args = [str(a) for a in self.request["args"]]  # type: ignore[attr-defined]
        _name_process(" ".join(args[:2]))
        import runpy

        # As `python -m` does: the command module runs afresh as __main__.
        sys.modules.pop("services.cli", None)
        sys.argv = ["services.cli", *args]
        runpy.run_module("services.cli", run_name="__main__", alter_sys=True)
        sys.exit(0)


def _path_as_at_start(cwd: str, pythonpath: str) -> None:
    """sys.path as a fresh ``python -m`` in ``cwd`` with this PYTHONPATH would have it, and
    what was installed since the server started: a test's own plugin directory on its
    PYTHONPATH, a package pip installed (its .pth file), its entry points."""
    import importlib
    import site

    sys.path[0] = cwd
    for position, entry in enumerate(e for e in pythonpath.split(os.pathsep) if e):
        if entry not in sys.path:
            sys.path.insert(1 + position, entry)
    for directory in site.getsitepackages():
        site.addsitedir(directory)  # reads .pth files again; paths already there stay once
    importlib.invalidate_caches()


def _name_process(name: str) -> None:
    """``ps -o comm`` and top show the command (15 bytes), not the server's."""
    with contextlib.suppress(OSError):
        Path("/proc/self/comm").write_text(f"wart {name}"[:15])


def serve(path: str) -> _Child | None:
    """Serve forks on the Unix socket ``path`` until the parent goes; in a child, return
    what it runs."""
    before = dict(os.environ)
    for module in PRELOAD:
        with contextlib.suppress(Exception):
            __import__(module)
    env_set = {k: v for k, v in os.environ.items() if before.get(k) != v}
    parent = os.getppid()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(64)
    selector = selectors.DefaultSelector()
    selector.register(listener, selectors.EVENT_READ)
    running: dict[int, socket.socket] = {}
    stopping: list[bool] = []
    signal.signal(signal.SIGTERM, lambda _sig, _frame: stopping.append(True))
    # A child's end wakes the loop at once (its exit code is what a test's wait waits
    # for): without it an exit was seen at the next 0.2 s turn, and a test that stops
    # five services, or a command line run to its end, waited up to that for each.
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda _sig, _frame: None)
    selector.register(wake_r, selectors.EVENT_READ)
    print("ready", flush=True)
    while os.getppid() == parent and not stopping:
        for key, _ in selector.select(timeout=0.2):
            if key.fileobj == wake_r:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 4096)
                continue
            sock = key.fileobj
            assert isinstance(sock, socket.socket)
            if sock is listener:
                conn, _ = listener.accept()
                selector.register(conn, selectors.EVENT_READ)
                continue
            try:
                data, fds, _, _ = socket.recv_fds(sock, 1 << 20, 3)
            except OSError:
                data, fds = b"", []
            selector.unregister(sock)
            if not data:
                sock.close()
                continue
            sys.stdout.flush()
            pid = os.fork()
            if pid == 0:
                signal.set_wakeup_fd(-1)
                os.close(wake_r)
                os.close(wake_w)
                selector.close()
                listener.close()
                for other in running.values():
                    other.close()
                sock.close()
                return _Child(json.loads(data), fds, env_set)
            for fd in fds:
                os.close(fd)
            running[pid] = sock
            _send(sock, {"pid": pid})
        _reap(running)
    _stop_all(running)
    return None


def _send(sock: socket.socket, message: dict[str, object]) -> None:
    with contextlib.suppress(OSError):
        sock.sendall(json.dumps(message).encode() + b"\n")


def _reap(running: dict[int, socket.socket]) -> None:
    while running:
        try:
            pid, status, usage = os.wait4(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        sock = running.pop(pid, None)
        if sock is not None:
            cpu = usage.ru_utime + usage.ru_stime
            _send(sock, {"exit": os.waitstatus_to_exitcode(status), "cpu_s": cpu})
            sock.close()


def _stop_all(running: dict[int, socket.socket]) -> None:
    """The parent went away (or stops the server): stop every process group still running,
    SIGTERM then SIGKILL."""
    for pid in running:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pid, signal.SIGTERM)
    deadline = time.monotonic() + STOP_GRACE_S
    while running and time.monotonic() < deadline:
        _reap(running)
        time.sleep(0.05)
    for pid in running:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pid, signal.SIGKILL)
    _reap(running)


def main(argv: Sequence[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1 or args[0].startswith("-"):
        print("usage: python -m tests.kit.forkserver SOCKET  (started by the test kit)")
        raise SystemExit(2)
    child = serve(args[0])
    if child is not None:
        child.run()


# --- the client ----------------------------------------------------------------------


class Running(Protocol):
    """What the kit's users call on a started process: a subprocess.Popen or a ForkedProcess."""

    @property
    def pid(self) -> int: ...

    @property
    def returncode(self) -> int | None: ...

    def poll(self) -> int | None: ...

    def wait(self, timeout: float | None = None) -> int: ...

    def send_signal(self, sig: int) -> None: ...

    def terminate(self) -> None: ...

    def kill(self) -> None: ...


class ForkedProcess:
    """The part of subprocess.Popen the kit's users call, for a process the server forked."""

    def __init__(self, args: Sequence[str], sock: socket.socket) -> None:
        self.args = list(args)
        self._sock = sock
        self._buffer = b""
        self._lock = threading.Lock()
        self.returncode: int | None = None
        self.cpu_s = 0.0
        try:
            first = self._read_message(60.0)
        except EOFError:
            first = None
        if first is None or "pid" not in first:
            raise OSError(f"the fork server did not start {' '.join(args)}")
        self.pid = int(first["pid"])  # type: ignore[call-overload]

    def _read_message(self, timeout: float) -> dict[str, object] | None:
        """The next message, or None when ``timeout`` runs out; EOFError when the server
        closed the connection without one (it went away, and stopped its children)."""
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buffer:
            self._sock.settimeout(max(0.0, deadline - time.monotonic()))
            try:
                chunk = self._sock.recv(4096)
            except (TimeoutError, BlockingIOError):
                return None
            if not chunk:
                raise EOFError
            self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        message: dict[str, object] = json.loads(line)
        return message

    def _collect(self, timeout: float) -> None:
        with self._lock:
            if self.returncode is not None:
                return
            try:
                message = self._read_message(timeout)
            except (EOFError, OSError):
                self.returncode = -signal.SIGKILL
            else:
                if message is None:
                    return
                self.returncode = int(message["exit"])  # type: ignore[call-overload]
                self.cpu_s = float(message.get("cpu_s", 0.0))  # type: ignore[arg-type]
                _count_cpu(self.cpu_s)
            self._sock.close()

    def poll(self) -> int | None:
        self._collect(0.0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        # In short steps: another thread may poll meanwhile.
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.returncode is None:
            left = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
            if left <= 0:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            self._collect(left)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def __repr__(self) -> str:
        return f"<ForkedProcess pid={self.pid} returncode={self.returncode} {self.args[:2]}>"


_cpu_lock = threading.Lock()
_forked_cpu = [0.0]


def _count_cpu(seconds: float) -> None:
    with _cpu_lock:
        _forked_cpu[0] += seconds


def forked_cpu() -> float:
    """CPU seconds of every forked process that has ended (what RUSAGE_CHILDREN would count
    had this process started them itself)."""
    with _cpu_lock:
        return _forked_cpu[0]


class ForkServer:
    """This process's fork server, started on first use."""

    def __init__(self, repo: Path) -> None:
        self.repo = repo
        self._lock = threading.Lock()
        self._popen: subprocess.Popen[bytes] | None = None
        self._path: str | None = None

    def _started(self) -> str:
        with self._lock:
            if self._popen is not None and self._popen.poll() is None and self._path:
                return self._path
            directory = Path(os.environ.get("TMPDIR", "/tmp"))
            path = str(directory / f"wart-fork-{os.getpid()}-{time.monotonic_ns()}.sock")
            env = dict(os.environ)
            env["PYTHONPATH"] = str(self.repo) + os.pathsep + env.get("PYTHONPATH", "")
            popen = subprocess.Popen(
                [sys.executable, "-u", "-m", "tests.kit.forkserver", path],
                cwd=self.repo,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                start_new_session=True,
            )
            assert popen.stdout is not None
            ready = popen.stdout.readline()
            popen.stdout.close()
            if ready.strip() != b"ready":
                popen.kill()
                raise OSError(f"the fork server did not start (it said {ready!r})")
            self._popen, self._path = popen, path
            return path

    def spawn(
        self,
        args: Sequence[str],
        *,
        cwd: Path,
        env: dict[str, str],
        stdin: int,
        stdout: int,
        stderr: int,
    ) -> ForkedProcess:
        """``python -m services.cli ARGS``, forked; the three streams are file descriptors."""
        request = {"args": list(args), "cwd": str(cwd), "env": env}
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.connect(self._started())
            socket.send_fds(sock, [json.dumps(request).encode()], [stdin, stdout, stderr])
            return ForkedProcess(args, sock)
        except BaseException:
            sock.close()
            raise

    def stop(self) -> None:
        with self._lock:
            if self._popen is not None and self._popen.poll() is None:
                self._popen.terminate()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self._popen.wait(STOP_GRACE_S + 5)
            if self._path:
                with contextlib.suppress(OSError):
                    os.unlink(self._path)


def enabled() -> bool:
    return os.environ.get(ENABLED_ENV, "0") == "1" and sys.platform.startswith("linux")


if __name__ == "__main__":
    main()
