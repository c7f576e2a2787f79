"""Running an uploaded controller, which we do not trust, in a sandbox.

Layers, outermost first (each one alone would not be enough):

1. ``setpriv`` drops to an unprivileged uid/gid when the runner is root: the
   kernel ignores RLIMIT_NPROC for root, so without this a fork bomb is free.
2. ``prlimit`` sets CPU time, address space, processes, open files and file size.
3. ``bwrap --unshare-all`` gives new user, pid, network, IPC and UTS
   namespaces: no network at all, no view of other processes, and a file
   system of read-only /usr plus a tmpfs working directory. No /root, no
   /home, no keys, no Zenoh session.
4. A wall-clock kill at the end of the slot, of the whole process group.

The child is Debian's ``/usr/bin/python3`` running services/runner/child.py
with only the standard library and common/controller.py. It talks to this
parent over pipes, one JSON object per line; every line it sends is checked
(:func:`validate_command`) before anything reaches a robot.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import psutil

from common import controller as controller_api
from common.precheck import MAX_SOURCE_BYTES, PrecheckError, precheck

log = logging.getLogger("wart.runner.sandbox")

__all__ = ["MAX_SOURCE_BYTES", "PrecheckError", "Sandbox", "SandboxLimits", "precheck"]

MAX_LINE_BYTES = 4096
SANDBOX_PYTHON = "/usr/bin/python3"
_CHILD = Path(__file__).with_name("child.py")
_API = Path(controller_api.__file__)


@dataclass(frozen=True)
class SandboxLimits:
    cpu_seconds: int = 120
    memory_bytes: int = 256 * 1024 * 1024
    processes: int = 16
    open_files: int = 64
    file_size_bytes: int = 1024 * 1024
    output_lines_per_second: int = 50
    commands_per_second: int = 200


def validate_command(message: dict[str, Any]) -> controller_api.RobotCommand:
    """One command from the sandbox, checked; ValueError (saying why) if it is not one."""
    return controller_api.RobotCommand.from_dict(message)


def sandbox_problem() -> str | None:
    """None if sandboxes can run here, else what is missing."""
    if shutil.which("bwrap") is None:
        return "bubblewrap is not installed (Debian package bubblewrap)"
    if not Path(SANDBOX_PYTHON).exists():
        return f"{SANDBOX_PYTHON} is missing (Debian package python3)"
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        return "setpriv is missing (Debian package util-linux)"
    if shutil.which("prlimit") is None:
        return "prlimit is missing (Debian package util-linux)"
    return None


_uid_lock = threading.Lock()
_uids_in_use: set[int] = set()
_UID_BASE = 61000


def _take_uid() -> int:
    # A uid of its own per sandbox: RLIMIT_NPROC counts processes per uid, so a
    # uid that still owns anything (even a zombie left by a crash) is skipped.
    busy = {p.info["uids"].real for p in psutil.process_iter(["uids"]) if p.info["uids"]}
    with _uid_lock:
        uid = next(
            u for u in range(_UID_BASE, _UID_BASE + 1000) if u not in _uids_in_use and u not in busy
        )
        _uids_in_use.add(uid)
        return uid


def _give_uid(uid: int) -> None:
    with _uid_lock:
        _uids_in_use.discard(uid)


class Sandbox:
    """One run of one uploaded controller.

    ``on_command`` gets each validated command; ``on_output`` each line the
    controller printed (or its traceback); ``on_exit`` a one-line reason once
    the child is gone. All callbacks run on the sandbox's reader threads.
    """

    def __init__(
        self,
        source: bytes,
        *,
        filename: str = "controller.py",
        limits: SandboxLimits | None = None,
        on_command: Callable[[controller_api.RobotCommand], None],
        on_output: Callable[[str], None],
        on_exit: Callable[[str], None] = lambda reason: None,
    ) -> None:
        self.controller_name = precheck(source, filename)
        problem = sandbox_problem()
        if problem:
            raise RuntimeError(f"cannot sandbox uploaded code: {problem}")
        self.source = source
        self.limits = limits or SandboxLimits()
        self.on_command = on_command
        self.on_output = on_output
        self.on_exit = on_exit
        self.rejected_commands = 0
        self.process: subprocess.Popen[bytes] | None = None
        self._stage: Path | None = None
        self._uid: int | None = None
        self._cmd_read: int | None = None
        self._lock = threading.Lock()
        self._stopping = False
        self._stop_reason = ""
        self._exit_reason = ""
        self._done = threading.Event()
        self._kill_timer: threading.Timer | None = None

    # -- start

    def _stage_files(self) -> Path:
        stage = Path(tempfile.mkdtemp(prefix="wart-sandbox-"))
        (stage / "lib" / "common").mkdir(parents=True)
        (stage / "user").mkdir()
        shutil.copy(_CHILD, stage / "child.py")
        shutil.copy(_API, stage / "lib" / "common" / "controller.py")
        (stage / "lib" / "common" / "__init__.py").write_text("")
        (stage / "user" / "controller.py").write_bytes(self.source)
        for path in [stage, *stage.rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)
        return stage

    def command_line(self, stage: Path, cmd_fd: int) -> list[str]:
        lim = self.limits
        argv: list[str] = []
        if os.geteuid() == 0:
            self._uid = _take_uid()
            argv += ["setpriv", f"--reuid={self._uid}", f"--regid={self._uid}", "--clear-groups"]
        argv += [
            "prlimit",
            f"--cpu={lim.cpu_seconds}",
            f"--as={lim.memory_bytes}",
            f"--nproc={lim.processes}",
            f"--nofile={lim.open_files}",
            f"--fsize={lim.file_size_bytes}",
            "--",
            "bwrap",
            "--unshare-all",
            "--die-with-parent",
            "--new-session",
            "--ro-bind",
            "/usr",
            "/usr",
            "--symlink",
            "usr/lib",
            "/lib",
            "--symlink",
            "usr/lib64",
            "/lib64",
            "--symlink",
            "usr/bin",
            "/bin",
            "--ro-bind",
            str(stage),
            "/ctl",
            "--tmpfs",
            "/work",
            "--tmpfs",
            "/tmp",
            "--proc",
            "/proc",
            "--dev",
            "/dev",
            "--chdir",
            "/work",
            "--clearenv",
            "--setenv",
            "PATH",
            "/usr/bin",
            "--setenv",
            "HOME",
            "/work",
            "--setenv",
            "PYTHONDONTWRITEBYTECODE",
            "1",
            "--",
            SANDBOX_PYTHON,
            "-I",
            "-S",
            "-u",
            "/ctl/child.py",
            str(cmd_fd),
            "/ctl/user/controller.py",
        ]
        return argv

    def start(self, slot_seconds: float) -> None:
        """Start the controller; it is killed ``slot_seconds`` from now at the latest."""
        self._stage = self._stage_files()
        cmd_read, cmd_write = os.pipe()
        self._cmd_read = cmd_read
        try:
            self.process = subprocess.Popen(
                self.command_line(self._stage, cmd_write),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                pass_fds=(cmd_write,),
                start_new_session=True,
            )
        except OSError:
            os.close(cmd_read)
            self._cleanup_files()
            raise
        finally:
            os.close(cmd_write)
        threading.Thread(target=self._read_commands, daemon=True, name="sandbox-cmd").start()
        threading.Thread(target=self._read_output, daemon=True, name="sandbox-out").start()
        threading.Thread(target=self._wait, daemon=True, name="sandbox-wait").start()
        self._kill_timer = threading.Timer(slot_seconds, self._slot_over)
        self._kill_timer.daemon = True
        self._kill_timer.start()

    # -- relaying

    def send_state(self, state: dict[str, Any]) -> bool:
        """Hand the newest robot state to the controller; False once it has gone."""
        line = (json.dumps({"t": "state", **state}, separators=(",", ":")) + "\n").encode()
        proc = self.process
        if proc is None or proc.stdin is None or proc.poll() is not None:
            return False
        try:
            proc.stdin.write(line)
            proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError, ValueError):
            return False

    def _read_commands(self) -> None:
        assert self._cmd_read is not None
        budget = _RateBudget(self.limits.commands_per_second)
        with os.fdopen(self._cmd_read, "rb") as pipe:
            for raw in pipe:
                if len(raw) > MAX_LINE_BYTES:
                    self.rejected_commands += 1
                    continue
                try:
                    message = json.loads(raw)
                    if not isinstance(message, dict):
                        raise ValueError("not an object")
                except ValueError:
                    self.rejected_commands += 1
                    continue
                kind = message.get("t")
                if kind == "cmd":
                    try:
                        command = validate_command(message)
                    except ValueError as exc:
                        self.rejected_commands += 1
                        self._say(f"[runner] command refused: {exc}")
                        continue
                    if budget.take():
                        self.on_command(command)
                    else:
                        self.rejected_commands += 1
                elif kind == "ready":
                    self._say(f"[runner] controller {str(message.get('controller'))[:64]} started")
                elif kind == "error":
                    self._exit_reason = "the controller raised an exception"
                    for line in str(message.get("message", ""))[:4000].splitlines():
                        self._say(line)
                elif kind == "done":
                    self._exit_reason = self._stop_reason or "the controller finished"

    def _read_output(self) -> None:
        proc = self.process
        assert proc is not None and proc.stdout is not None
        budget = _RateBudget(self.limits.output_lines_per_second)
        dropped = 0
        for raw in proc.stdout:
            if budget.take():
                if dropped:
                    self._say(
                        f"[runner] {dropped} output lines dropped (over "
                        f"{self.limits.output_lines_per_second} lines/s)"
                    )
                    dropped = 0
                self._say(raw[:1000].decode("utf-8", "replace").rstrip("\n"))
            else:
                dropped += 1

    def _say(self, line: str) -> None:
        try:
            self.on_output(line)
        except Exception:
            log.exception("output callback failed")

    def _wait(self) -> None:
        proc = self.process
        assert proc is not None
        code = proc.wait()
        if self._kill_timer is not None:
            self._kill_timer.cancel()
        if not self._exit_reason:
            if self._stopping:
                self._exit_reason = self._stop_reason
            elif code == -signal.SIGXCPU or code == 128 + signal.SIGXCPU:
                self._exit_reason = "killed: it used up its CPU time"
            elif code < 0:
                self._exit_reason = f"killed by {signal.Signals(-code).name}"
            else:
                self._exit_reason = f"exited with code {code}"
        self._cleanup_files()
        self._done.set()
        try:
            self.on_exit(self._exit_reason)
        except Exception:
            log.exception("exit callback failed")

    # -- stopping

    def _slot_over(self) -> None:
        self.stop(grace=0.5, reason="stopped at the end of its slot")

    def stop(self, grace: float = 1.0, reason: str = "stopped") -> None:
        """Ask the controller to clean up, then kill its whole process group."""
        with self._lock:
            if self._stopping:
                return
            self._stopping = True
            self._stop_reason = reason
        proc = self.process
        if proc is None:
            return
        if proc.poll() is None and proc.stdin is not None:
            try:
                proc.stdin.write(b'{"t":"stop"}\n')
                proc.stdin.close()
            except (BrokenPipeError, OSError, ValueError):
                pass
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            if not self._exit_reason:
                self._exit_reason = reason
            _kill_sandbox(proc)
        self._done.wait(5.0)

    def wait(self, timeout: float | None = None) -> bool:
        return self._done.wait(timeout)

    @property
    def exit_reason(self) -> str:
        return self._exit_reason

    def _cleanup_files(self) -> None:
        if self._stage is not None:
            shutil.rmtree(self._stage, ignore_errors=True)
            self._stage = None
        if self._uid is not None:
            _give_uid(self._uid)
            self._uid = None


def _kill_sandbox(proc: subprocess.Popen[bytes]) -> None:
    """Kill a sandbox so that nothing is left, not even a zombie.

    The outer bwrap (our child) runs an inner bwrap as init of the sandbox's
    pid namespace. Killing that init makes the kernel kill and reap every
    process inside; the outer bwrap then reaps it and exits. Killing the outer
    one first would orphan the inner one to the machine's init, and where that
    init does not reap (containers), zombies pile up and count against
    RLIMIT_NPROC for the sandbox's uid.
    """
    try:
        inner = psutil.Process(proc.pid).children()
    except psutil.Error:
        inner = []
    for child in inner:
        with contextlib.suppress(psutil.Error):
            child.kill()
    try:
        proc.wait(2.0)
        return
    except subprocess.TimeoutExpired:
        pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


class _RateBudget:
    """A token bucket: ``rate`` events per second, bursts up to one second's worth."""

    def __init__(self, rate: int) -> None:
        self.rate = float(rate)
        self.tokens = float(rate)
        self.stamp = time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.tokens = min(self.rate, self.tokens + (now - self.stamp) * self.rate)
        self.stamp = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False
