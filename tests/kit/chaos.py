"""Chaos on a running ``wart up`` lab: kill -9 a service with clients attached, time the way back.

:class:`Chaos` kills the lab's children one at a time and times how long until
each is back (every liveliness token present before the kill present again) and
how long until the clients are whole again without any user action (a terminal
chat client's new line reaches a second one through the room); a fresh client
then reads the room's history for the lines acknowledged before the kills.
bench/bench_chaos.py prints the figures; tests/smoke/test_chaos.py asserts them.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

import psutil

from common import keys
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab.supervisor import AliveWatch
from tests.kit.lab import UpLab
from tests.kit.procs import REPO, wart_env

# The children of a default `wart up`, named by their subcommand and --name (or --world).
SERVICES = (
    "router",
    "registry",
    "context chat lobby",
    "engine arena1",
    "runner runner",
    "context agent arena",
    "bridge real1",
    "viewer",
)


def lab_env() -> dict[str, str]:
    """A person's tool's environment: the lab's (tests/kit/lab.py), no credentials of this shell."""
    return wart_env()


class Lines:
    """A child's output lines, read by a thread, searchable from any point on."""

    def __init__(self, popen: subprocess.Popen[str]) -> None:
        self.popen = popen
        self.lines: list[str] = []
        self._queue: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append(line.rstrip("\n"))
            self._queue.put(line.rstrip("\n"))

    def wait(self, needle: str, timeout: float, since: int = 0) -> str | None:
        deadline = time.monotonic() + timeout
        seen = since
        while True:
            while seen < len(self.lines):
                if needle in self.lines[seen]:
                    return self.lines[seen]
                seen += 1
            if time.monotonic() > deadline or self.popen.poll() is not None:
                return None
            with suppress(queue.Empty):
                self._queue.get(timeout=0.05)


class ChaosLab(UpLab):
    """``wart up`` in a subprocess on free ports with its own realm and state directory
    (tests/kit/lab.py's UpLab, the one starter), and what the chaos run asks of it."""

    def __init__(self, state_dir: Path) -> None:
        super().__init__(realm=f"chaos{os.getpid()}", state_dir=state_dir)

    def start(self, timeout: float = 180.0) -> ChaosLab:
        super().start()
        try:
            self.wait_line("The lab is running", timeout)
        except AssertionError:
            self.stop()
            raise RuntimeError("the lab did not come up:\n" + "\n".join(self.lines)) from None
        return self

    def admin_password(self) -> str:
        return (self.state_dir / "admin-password.txt").read_text().strip()

    def registry_key(self) -> str:
        with suppress(AssertionError):
            line = self.wait_line("registry key", 1.0)
            return line.split(":", 1)[1].split()[0] if ":" in line else ""
        return ""

    def service(self, service: str) -> psutil.Process | None:
        """The running child whose command line is ``wart SERVICE ...`` (words in order)."""
        words = service.split()
        for proc in self.children():
            try:
                cmd = proc.cmdline()
            except psutil.NoSuchProcess:
                continue
            if "services.cli" not in cmd:
                continue
            args = cmd[cmd.index("services.cli") + 1 :]
            if args[:1] != words[:1]:
                continue
            if len(words) == 1 or _names(args, words[1:]):
                return proc
        return None

    def stop(self, timeout: float = 40.0) -> int:
        if self.popen is None or self.popen.poll() is not None:
            return self.popen.returncode if self.popen is not None else 0
        # A chaos run reports what it measured even if the lab is slow to stop.
        try:
            return super().stop(timeout)
        except AssertionError as exc:
            print(f"  {exc}", flush=True)
            return -1


def _names(args: Sequence[str], words: Sequence[str]) -> bool:
    """``context agent arena`` matches ``context agent ... --name arena``; ``engine arena1``
    matches ``engine ... --world arena1``."""
    rest = list(words)
    if rest and len(args) > 1 and args[1] == rest[0]:
        rest = rest[1:]
    if not rest:
        return True
    for flag in ("--name", "--world"):
        if (
            flag in args
            and args.index(flag) + 1 < len(args)
            and args[args.index(flag) + 1] == rest[0]
        ):
            return True
    return False


def wart_client(
    lab: ChaosLab, args: list[str], password: str, *, stdin: int | None = None
) -> subprocess.Popen[str]:
    """``wart ARGS`` as a person on this lab runs it (password and registry key from the env)."""
    env = lab_env()
    env["WART_PASSWORD"] = password
    env["WART_REGISTRY_KEY"] = lab.registry_key()
    net = ["--realm", lab.realm, "--connect", lab.endpoint, "--no-multicast-scouting"]
    return subprocess.Popen(
        [sys.executable, "-m", "services.cli", *args, *net],
        cwd=REPO,
        stdin=subprocess.DEVNULL if stdin is None else stdin,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        start_new_session=True,
    )


class ChatProbe:
    """``wart chat lobby`` as a user types it, in a subprocess."""

    def __init__(self, lab: ChaosLab, user: str, password: str) -> None:
        self.popen = wart_client(
            lab, ["chat", "lobby", "--user", user], password, stdin=subprocess.PIPE
        )
        self.output = Lines(self.popen)

    def say(self, text: str) -> None:
        assert self.popen.stdin is not None
        self.popen.stdin.write(text + "\n")
        self.popen.stdin.flush()

    def close(self) -> None:
        if self.popen.poll() is None:
            try:
                self.say("/quit")
                self.popen.wait(5)
            except (OSError, subprocess.TimeoutExpired):
                self.popen.kill()
                self.popen.wait(5)


class DeployProbe:
    """``wart deploy`` of example 01 on the arena's k0, as a student runs it."""

    def __init__(self, lab: ChaosLab, password: str) -> None:
        example = str(REPO / "examples" / "01_braitenberg.py")
        args = ["deploy", example, "--context", "arena", "--agent", "k0", "--user", "admin"]
        self.popen = wart_client(lab, args, password)
        self.output = Lines(self.popen)

    def ending(self, timeout: float) -> str:
        """How it ended: its last line once it exits (or 'still running')."""
        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            return "still running"
        time.sleep(0.2)  # the reader thread takes the last lines
        return self.output.lines[-1] if self.output.lines else f"exit {self.popen.returncode}"

    def close(self) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(10)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5)


@dataclass
class Outcome:
    service: str
    back_s: float | None  # every token present before the kill present again
    whole_s: float | None  # a new chat line goes through the room again
    note: str = ""


@contextmanager
def running_lab(state_dir: Path | None = None) -> Iterator[ChaosLab]:
    tmp = Path(tempfile.mkdtemp(prefix="wart-chaos-")) if state_dir is None else state_dir
    lab = ChaosLab(tmp / "state")
    lab.start()
    try:
        yield lab
    finally:
        lab.stop()


class Chaos:
    """Kills services one at a time and times the way back."""

    def __init__(self, lab: ChaosLab, deadline_s: float = 30.0) -> None:
        self.lab = lab
        self.deadline_s = deadline_s
        password = lab.admin_password()
        self.talker = ChatProbe(lab, "admin", password)
        self.listener = ChatProbe(lab, "admin", password)
        self.acknowledged: list[str] = []  # lines the other client saw: the room had them
        self._n = 0
        session_options = NetworkOptions(realm=lab.realm, connect=(lab.endpoint,))
        self.session = open_session(session_options, wait=20.0)
        self.watch = AliveWatch(self.session, keys.alive_all(lab.realm))
        for probe in (self.talker, self.listener):
            if probe.output.wait("here:", 30) is None:
                raise RuntimeError("a chat client did not join:\n" + "\n".join(probe.output.lines))

    def _line_goes_through(self, tag: str, timeout: float) -> float | None:
        """Say fresh lines until the listener sees one; the time it took, or None."""
        start = time.monotonic()
        since = len(self.listener.output.lines)
        while time.monotonic() - start < timeout:
            self._n += 1
            text = f"{tag}-{self._n}"
            self.talker.say(text)
            if self.listener.output.wait(text, 0.5, since) is not None:
                self.acknowledged.append(text)
                return time.monotonic() - start
        return None

    def kill(self, service: str) -> Outcome:
        if self._line_goes_through(f"before-{service.replace(' ', '_')}", 10) is None:
            return Outcome(service, None, None, "the chat was not working before the kill")
        victim = self.lab.service(service)
        if victim is None:
            return Outcome(service, None, None, "no such child")
        tokens = self.watch.keys()
        killed_at = time.monotonic()
        victim.kill()
        back_s = None
        # The old tokens go (the router's: all of them) and come back under new sessions.
        deadline = killed_at + self.deadline_s
        while time.monotonic() < deadline:
            new = self.lab.service(service)
            if new is not None and new.pid != victim.pid and tokens <= self.watch.keys():
                back_s = time.monotonic() - killed_at
                break
            time.sleep(0.02)
        whole = self._line_goes_through(
            f"after-{service.replace(' ', '_')}", max(1.0, deadline - time.monotonic())
        )
        whole_s = None if whole is None else time.monotonic() - killed_at
        return Outcome(service, back_s, whole_s)

    def lost_lines(self) -> list[str]:
        """Acknowledged lines missing from the room's history, as a new client reads it."""
        reader = ChatProbe(self.lab, "admin", self.lab.admin_password())
        try:
            reader.output.wait("here:", 30)
            last = self.acknowledged[-1] if self.acknowledged else ""
            reader.output.wait(last, 10)
            text = "\n".join(reader.output.lines)
            return [line for line in self.acknowledged if line not in text]
        finally:
            reader.close()

    def close(self) -> None:
        for probe in (self.talker, self.listener):
            probe.close()
        self.watch.close()
        close_session(self.session)
