"""A whole ``wart up`` lab in a subprocess, for smoke and browser tests."""

from __future__ import annotations

import queue
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import psutil

from services.lab.supervisor import start_wart
from services.lab.wiring import up_args
from tests.conftest import REPO, free_port, wart_env


@dataclass
class Lab:
    realm: str
    state_dir: Path
    port: int = field(default_factory=free_port)
    http_port: int = field(default_factory=free_port)
    extra_args: list[str] = field(default_factory=list)
    popen: subprocess.Popen[str] | None = None
    lines: list[str] = field(default_factory=list)
    _queue: queue.Queue[str] = field(default_factory=queue.Queue)

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def start(self) -> Lab:
        self.popen = start_wart(
            up_args(self.realm, self.state_dir, self.port, self.http_port, *self.extra_args),
            env=wart_env(),
            cwd=REPO,
        )
        threading.Thread(target=self._read, daemon=True).start()
        return self

    def _read(self) -> None:
        assert self.popen is not None and self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append(line.rstrip("\n"))
            self._queue.put(line)

    def wait_line(self, needle: str, timeout: float = 60.0) -> str:
        """The first output line (from now on, or already seen) containing ``needle``."""
        for line in self.lines:
            if needle in line:
                return line
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self._queue.get(timeout=0.2)
            except queue.Empty:
                if self.popen is not None and self.popen.poll() is not None:
                    break
                continue
            if needle in line:
                return line
        raise AssertionError(
            f"no line with {needle!r} within {timeout:.0f} s; output:\n" + "\n".join(self.lines)
        )

    def wait_new_line(self, needle: str, timeout: float = 60.0) -> str:
        """The next output line from now on containing ``needle``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            if needle in line:
                return line
        raise AssertionError(f"no new line with {needle!r}; output:\n" + "\n".join(self.lines))

    def children(self) -> list[psutil.Process]:
        assert self.popen is not None
        try:
            return psutil.Process(self.popen.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []

    def child(self, subcommand: str) -> psutil.Process:
        """The child process running ``wart SUBCOMMAND``."""
        for proc in self.children():
            try:
                cmd = proc.cmdline()
            except psutil.NoSuchProcess:
                continue
            if "services.cli" in cmd and cmd[cmd.index("services.cli") + 1] == subcommand:
                return proc
        raise AssertionError(f"no child running wart {subcommand}")

    def stop(self, timeout: float = 30.0) -> int:
        assert self.popen is not None
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                for proc in self.children():
                    proc.kill()
                self.popen.kill()
                self.popen.wait(5)
                raise AssertionError(
                    f"wart up did not stop within {timeout:.0f} s of Ctrl-C"
                ) from None
        return self.popen.returncode
