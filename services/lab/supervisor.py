"""Supervision of a host's child processes (used by ``wart up`` and ``wart host``).

Children start in order; each is "up" when its liveliness token appears (never
after a fixed sleep). A child that exits is restarted with exponential backoff
(reset once it has run for a while), and the operator is told why it died. On
stop, children get SIGTERM in reverse order, then SIGKILL after a deadline;
each child also asks the kernel to SIGTERM it should the supervisor die
(``WART_PARENT_PID``, see services/cli.py), so no child outlives the lab.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from common.log import RotatingFile, pump

log = logging.getLogger("wart.supervisor")

# A first crash is most likely a one-off (a killed process, a router blip): restart at
# once. A crash loop still backs off: 0.1, 0.5, 1, 2, 4 ... 30 s.
BACKOFF_FIRST = 0.1
BACKOFF_SECOND = 0.5
BACKOFF_MAX = 30.0
STABLE_AFTER = 60.0  # a child that ran this long starts again from the first backoff


@dataclass
class ChildSpec:
    """One process to keep running."""

    name: str  # what the operator reads: "registry", "engine arena"
    argv: Sequence[str]  # arguments of ``wart`` (the subcommand first)
    alive_key: str | None  # the liveliness key that says it is serving
    detail: str = ""  # shown beside the name once up (an endpoint, a map)
    ready_timeout: float = 60.0
    env: dict[str, str] = field(default_factory=dict)
    # What must exist before the process starts (a generated map, a directory),
    # done at each spawn rather than when the plan is made: a plan is data, so
    # `wart doctor` can compute a host's plan without writing on its disk.
    prepare: Callable[[], object] | None = None


@dataclass
class Child:
    spec: ChildSpec
    log_path: Path
    log: RotatingFile | None = None
    pump: threading.Thread | None = None  # copies the child's output into ``log``
    process: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    restarts: int = 0
    backoff: float = BACKOFF_FIRST
    restart_at: float | None = None


def next_backoff(current: float) -> float:
    """The wait before the restart after the one that waited ``current``."""
    if current < BACKOFF_SECOND:
        return BACKOFF_SECOND
    return min(max(current * 2, 1.0), BACKOFF_MAX)


def wart_command(args: Sequence[str]) -> list[str]:
    """The command line that runs ``wart ARGS`` with this interpreter."""
    return [sys.executable, "-m", "services.cli", *args]


def start_wart(
    args: Sequence[str], *, env: dict[str, str] | None = None, cwd: Path | None = None
) -> subprocess.Popen[str]:
    """``wart ARGS`` in its own process group, output (stderr too) piped as text lines.

    Its own group, so a stop can signal the whole tree (``os.killpg``), and a
    Ctrl-C in the caller's terminal does not reach it twice.
    """
    return subprocess.Popen(
        wart_command(args),
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        start_new_session=True,
    )


def describe_exit(code: int) -> str:
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        extra = " (killed)" if -code == signal.SIGKILL else ""
        return f"was stopped by {name}{extra}"
    return f"exited with code {code}"


STILL_STARTING_S = 8.0  # a child not up by then is said to be still starting
STARTING_EVERY_S = 30.0  # and said again this often, with how long so far


def tail(path: Path, lines: int = 6) -> str:
    try:
        with open(path, "rb") as f:
            f.seek(max(0, f.seek(0, os.SEEK_END) - 65536))
            text = f.read().decode(errors="replace").splitlines()
    except OSError:
        return ""
    return "\n".join(f"      | {line}" for line in text[-lines:])


class AliveWatch:
    """The set of liveliness keys currently present under a key expression."""

    def __init__(self, session: zenoh.Session, key_expr: str) -> None:
        self._present: set[str] = set()
        self._cond = threading.Condition()
        self._sub = session.liveliness().declare_subscriber(key_expr, self._on, history=True)

    def _on(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self._present.add(key)
            else:
                self._present.discard(key)
            self._cond.notify_all()

    def present(self, key: str) -> bool:
        with self._cond:
            return key in self._present

    def keys(self) -> set[str]:
        with self._cond:
            return set(self._present)

    def wait(self, key: str, timeout: float, abort: Callable[[], bool] = lambda: False) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while key not in self._present:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or abort():
                    return False
                self._cond.wait(min(remaining, 0.2))
            return True

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception as exc:
            log.debug("liveliness subscriber: %s", exc)


class Supervisor:
    """Starts, watches, restarts and stops a list of children."""

    def __init__(self, log_dir: Path, *, say: Callable[[str], None] = print) -> None:
        self.log_dir = log_dir
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.say = say
        self.children: list[Child] = []
        self.watch: AliveWatch | None = None
        self._stopping = threading.Event()
        self._lock = threading.Lock()

    # -- starting

    def spawn(self, child: Child) -> None:
        if child.spec.prepare is not None:
            child.spec.prepare()
        env = dict(os.environ)
        env.update(child.spec.env)
        env["WART_PARENT_PID"] = str(os.getpid())
        env.setdefault("PYTHONUNBUFFERED", "1")
        if child.log is None:
            child.log = RotatingFile(child.log_path)
        child.log.write(f"\n--- started {time.strftime('%Y-%m-%d %H:%M:%S')} ---\n".encode())
        # The child writes to a pipe that this process copies into a file rotated at a
        # size cap: a child flooding its output cannot fill the disk.
        read_end, write_end = os.pipe()
        try:
            child.process = subprocess.Popen(
                wart_command(child.spec.argv),
                stdin=subprocess.DEVNULL,
                stdout=write_end,
                stderr=subprocess.STDOUT,
                env=env,
                # Ctrl-C reaches the supervisor only; it stops the children in order.
                start_new_session=True,
            )
        except BaseException:
            os.close(read_end)
            raise
        finally:
            os.close(write_end)
        child.pump = threading.Thread(
            target=pump, args=(read_end, child.log), name=f"log {child.spec.name}", daemon=True
        )
        child.pump.start()
        child.started_at = time.monotonic()
        child.restart_at = None

    def add(self, spec: ChildSpec) -> Child:
        safe = spec.name.replace(" ", "-").replace("/", "-")
        child = Child(spec=spec, log_path=self.log_dir / f"{safe}.log")
        with self._lock:
            self.children.append(child)
        return child

    def start(self, spec: ChildSpec) -> bool:
        """Start a child and wait until it is alive; False if it did not come up in time."""
        child = self.add(spec)
        self.spawn(child)
        return self.wait_ready(child)

    def start_together(
        self, specs: Sequence[ChildSpec], on_up: Callable[[Child], None] | None = None
    ) -> list[tuple[Child, bool]]:
        """Start children at once and wait until each is alive: their starts overlap.

        Each child's ready line is said as it comes up, and ``on_up(child)`` called
        then (the web address is printed while a slower child still starts); the
        result keeps the order of ``specs``, with False for a child that did not
        come up in time.
        """
        children = [self.add(spec) for spec in specs]
        for child in children:
            self.spawn(child)
        ready = [False] * len(children)

        def wait(index: int) -> None:
            ready[index] = self.wait_ready(children[index], on_late_up=on_up)
            if ready[index] and on_up is not None:
                on_up(children[index])

        waiters = [
            threading.Thread(target=wait, args=(i,), name=f"ready {c.spec.name}", daemon=True)
            for i, c in enumerate(children)
        ]
        for waiter in waiters:
            waiter.start()
        for waiter in waiters:
            waiter.join()
        return list(zip(children, ready, strict=True))

    def wait_ready(self, child: Child, on_late_up: Callable[[Child], None] | None = None) -> bool:
        """Wait until ``child`` is alive; False if not within its ready time.

        A child still running then is watched on: it is said (and ``on_late_up``
        called) when it comes up.
        """
        spec = child.spec
        proc = child.process
        if spec.alive_key is None or self.watch is None:
            # Nothing on the network to wait for (an emulator on a pty): say it started.
            detail = f"  {spec.detail}" if spec.detail else ""
            self.say(f"  ✓ {spec.name:<22} started{detail}  (pid {proc.pid if proc else '-'})")
            return True

        def died() -> bool:
            return self._stopping.is_set() or proc is None or proc.poll() is not None

        # A child slow to start (an engine compiling its kernels on a checkout's first
        # start, on a busy machine for minutes) is said to be starting, with how long so
        # far and its log's last line, so nobody wonders.
        started = time.monotonic()
        alive_key = spec.alive_key
        ok = self.watch.wait(alive_key, min(STILL_STARTING_S, spec.ready_timeout), abort=died)
        while not ok and not died():
            so_far = time.monotonic() - started
            if so_far >= spec.ready_timeout:
                break
            self._say_starting(child, so_far)
            step = min(STARTING_EVERY_S, spec.ready_timeout - so_far)
            ok = self.watch.wait(alive_key, step, abort=died)
        if ok:
            self._say_up(child, started)
        elif self._stopping.is_set():
            pass
        elif proc is not None and proc.poll() is None:
            # Alive but not up yet: not a failure, which would turn out false minutes later.
            so_far = time.monotonic() - started
            self.say(
                f"  … {spec.name:<22} not up after {so_far:.0f} s but still starting: the rest "
                f"of the lab goes on, and it is said here when it is up (log {child.log_path})"
            )
            threading.Thread(
                target=self._wait_late,
                args=(child, started, on_late_up),
                name=f"late {spec.name}",
                daemon=True,
            ).start()
        else:
            why = describe_exit(proc.returncode) if proc is not None else "it did not start"
            self.say(f"  ✗ {spec.name:<22} did not come up: {why}; log {child.log_path}")
            text = tail(child.log_path)
            if text:
                self.say(text)
        return ok

    def _say_starting(self, child: Child, so_far: float) -> None:
        last = tail(child.log_path, lines=1).strip().removeprefix("| ")
        self.say(
            f"  … {child.spec.name:<22} still starting ({so_far:.0f} s so far)"
            + (f": {last}" if last else "")
        )

    def _say_up(self, child: Child, started: float) -> None:
        spec, proc = child.spec, child.process
        detail = f"  {spec.detail}" if spec.detail else ""
        took = time.monotonic() - started
        after = f", after {took:.0f} s" if took >= STILL_STARTING_S else ""
        self.say(f"  ✓ {spec.name:<22} up{detail}  (pid {proc.pid if proc else '-'}{after})")

    def _wait_late(
        self, child: Child, started: float, on_up: Callable[[Child], None] | None
    ) -> None:
        """A child past its ready time but alive: say when it comes up, or that it died."""
        proc = child.process
        assert self.watch is not None and child.spec.alive_key is not None

        def died() -> bool:
            return self._stopping.is_set() or proc is None or proc.poll() is not None

        while not died():
            if self.watch.wait(child.spec.alive_key, STARTING_EVERY_S, abort=died):
                self._say_up(child, started)
                if on_up is not None:
                    on_up(child)
                return
            self._say_starting(child, time.monotonic() - started)
        if not self._stopping.is_set() and proc is not None:
            why = describe_exit(proc.returncode)
            self.say(f"  ✗ {child.spec.name:<22} stopped before it was up: {why}")

    # -- watching

    def poll(self) -> None:
        """Restart children that exited, with backoff; call regularly."""
        now = time.monotonic()
        with self._lock:
            children = list(self.children)
        for child in children:
            if self._stopping.is_set():
                return
            proc = child.process
            if child.restart_at is not None:
                if now >= child.restart_at:
                    child.restarts += 1
                    self.say(f"  ↻ restarting {child.spec.name} (restart #{child.restarts})")
                    self.spawn(child)
                    threading.Thread(target=self.wait_ready, args=(child,), daemon=True).start()
                continue
            if proc is None or proc.poll() is None:
                continue
            ran = now - child.started_at
            if ran >= STABLE_AFTER:
                child.backoff = BACKOFF_FIRST
            self.say(
                f"  ! {child.spec.name} {describe_exit(proc.returncode)} after {ran:.1f} s; "
                f"restarting in {child.backoff:.1f} s (log {child.log_path})"
            )
            if child.pump is not None:
                child.pump.join(1.0)  # its last words reach the file before we show them
            text = tail(child.log_path, 4)
            if text:
                self.say(text)
            child.restart_at = now + child.backoff
            child.backoff = next_backoff(child.backoff)

    def run_until(self, stop: threading.Event, period: float = 0.2) -> None:
        while not stop.wait(period):
            self.poll()

    # -- stopping

    def stop_all(self, timeout: float = 8.0) -> None:
        """SIGTERM every child in reverse start order, SIGKILL what is left at the deadline."""
        self._stopping.set()
        with self._lock:
            children = list(reversed(self.children))
        for child in children:
            proc = child.process
            if proc is not None and proc.poll() is None:
                try:
                    proc.terminate()
                    proc.wait(timeout=max(0.5, timeout / max(1, len(children))))
                except subprocess.TimeoutExpired:
                    pass
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + timeout
        for child in children:
            proc = child.process
            if proc is None:
                continue
            try:
                proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say(f"  {child.spec.name} did not stop in time; killing it")
                proc.kill()
                proc.wait(timeout=5)
        if self.watch is not None:
            self.watch.close()

    def stop_child(self, child: Child, timeout: float = 8.0) -> None:
        """Stop one child for good (an arena being stopped) and forget it."""
        with self._lock:
            if child in self.children:
                self.children.remove(child)
        child.restart_at = None
        proc = child.process
        if proc is None or proc.poll() is not None:
            return
        proc.terminate()
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.say(f"  {child.spec.name} did not stop in time; killing it")
            proc.kill()
            proc.wait(timeout=5)

    def pids(self) -> list[int]:
        with self._lock:
            return [c.process.pid for c in self.children if c.process is not None]
