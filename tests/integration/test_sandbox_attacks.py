"""Hostile uploaded controllers, against the real sandbox (setpriv, prlimit,
bubblewrap, seccomp, cpu cgroup) driven the way the runner drives it.

This test process plays the runner: its memory is what must stay bounded, and
after every attack it must still run a well-behaved controller.
"""

from __future__ import annotations

import ast
import os
import queue
import textwrap
import threading
import time
from dataclasses import replace
from pathlib import Path

import psutil
import pytest

from common.controller import KheperaState, RobotCommand
from services.runner.cpushare import NICE_ONLY
from services.runner.sandbox import Sandbox, SandboxLimits, cpu_share
from tests.conftest import needs_sandbox, wait_for

pytestmark = needs_sandbox

HEADER = "from common.controller import Controller, Khepera\n"
STATE = KheperaState(time=1.0, proximity=(0, 0, 900, 0, 0, 0, 0, 0))
MB = 1 << 20


class Attack:
    """One hostile controller in a sandbox, its output collected."""

    def __init__(self, body: str, slot: float, limits: SandboxLimits | None = None) -> None:
        self.commands: queue.Queue[RobotCommand] = queue.Queue()
        self.output: list[str] = []
        self.sandbox = Sandbox(
            textwrap.dedent(HEADER + body).encode(),
            limits=limits,
            on_command=self.commands.put,
            on_output=self.output.append,
        )
        self.slot = slot
        self.started = time.monotonic()
        self.sandbox.start(slot)
        self.sandbox.send_state(STATE)

    def finish(self, timeout: float = 60.0) -> tuple[str, float]:
        """The reason it ended and how long after its start."""
        assert self.sandbox.wait(timeout), "the sandbox did not end"
        return self.sandbox.exit_reason, time.monotonic() - self.started

    def stop(self) -> float:
        """Stop it as the runner does at a slot's end: how long the stop took.

        Tests that need the controller to have run use this with a long slot,
        not a short slot: on a busy machine a short one can end before the
        sandbox's Python has even started.
        """
        began = time.monotonic()
        self.sandbox.stop(grace=0.5, reason="stopped by the runner")
        assert self.sandbox.wait(30), "the sandbox did not end"
        return time.monotonic() - began

    def text(self) -> str:
        return "\n".join(self.output)


def rss() -> int:
    return psutil.Process().memory_info().rss


def assert_still_serves() -> None:
    """The runner side runs the next, well-behaved controller as usual.

    Its slot is long and it is stopped once it has driven: on a busy machine a
    short slot can end before the sandbox has even started Python, and then the
    only command seen is the stop's (0, 0).
    """
    good = Attack(
        """
class Fine(Controller):
    period = 0.02
    def do_work(self, robot):
        robot.set_speeds(1, 2)
""",
        slot=60.0,
    )
    assert good.commands.get(timeout=30) == RobotCommand(speeds=(1, 2))
    good.sandbox.stop(grace=0.5, reason="stopped by the test")
    reason, _ = good.finish()
    assert reason == "stopped by the test"


def test_a_stalled_reader_ends_on_time_and_never_blocks_the_runner() -> None:
    # SIGSTOP freezes the whole child: nothing reads its stdin any more, and
    # the runner keeps sending states and then the stop message.
    attack = Attack(
        """
import os, signal
class Frozen(Controller):
    def initialize(self, robot):
        print("freezing", flush=True)
        os.kill(os.getpid(), signal.SIGSTOP)
    def do_work(self, robot):
        pass
""",
        slot=60.0,
    )
    wait_for(lambda: "freezing" in attack.text(), 30, "the controller to start")
    slowest = 0.0
    state = replace(STATE, ambient=(1000,) * 8)
    # States at 1 kHz, far above any engine's rate, fill the pipe within a
    # second. Not a hot loop: a thread writing to a full pipe without pause
    # starves the runner's other threads of the GIL (measured: the kill then
    # took 2 to 4 s to be seen), which no runner does.
    full_at: float | None = None
    while full_at is None or time.monotonic() < full_at + 0.5:
        began = time.monotonic()
        attack.sandbox.send_state(state)
        slowest = max(slowest, time.monotonic() - began)
        if full_at is None and attack.sandbox.dropped_states:
            full_at = time.monotonic()
        assert began - attack.started < 60, "the pipe to the stalled child never filled"
        time.sleep(0.001)
    took = attack.stop()
    assert slowest < 0.5, f"a write to the stalled child took {slowest:.2f} s"
    assert attack.sandbox.exit_reason == "stopped by the runner"
    steps = {k: round(v - attack.started, 2) for k, v in attack.sandbox.timeline.items()}
    # The grace of 0.5 s, then the kill: nothing the frozen child does can delay it.
    assert took < 5.0, (
        f"the stop took {took:.1f} s: {steps}, {threading.active_count()} threads in the runner"
    )
    assert "not reading its robot states" in attack.text()
    assert_still_serves()


def test_an_output_flood_without_newlines_is_ended_and_the_runner_stays_small() -> None:
    before = rss()
    attack = Attack(
        """
import sys
class Flood(Controller):
    def do_work(self, robot):
        print("y" * 100000)
        chunk = "x" * (1 << 20)
        while True:
            sys.stdout.write(chunk)
""",
        slot=60.0,
    )
    reason, _ = attack.finish()
    assert reason.startswith("killed: output flood"), reason
    assert "[runner: line cut at 1000 bytes]" in attack.text()
    assert max(len(line) for line in attack.output) < 2000
    assert rss() - before < 50 * MB, f"the runner grew by {(rss() - before) / MB:.0f} MB"
    assert_still_serves()


def test_many_big_files_fill_only_the_sandbox_quota() -> None:
    limits = SandboxLimits(memory_bytes=128 * MB)
    attack = Attack(
        """
class Filler(Controller):
    def initialize(self, robot):
        total = 0
        for where in ("/work", "/tmp", "/dev/shm", "/dev", "/"):
            try:
                for i in range(1200):
                    with open(f"{where}/f{i}", "wb") as f:
                        f.write(b"z" * (1 << 20))
                    total += 1
            except OSError as exc:
                print(where, "refused after", i, "files:", exc.strerror)
        print("wrote MB", total)
        open("/work/last", "wb").write(b"z" * (1 << 20))
    def do_work(self, robot):
        pass
""",
        slot=60.0,
        limits=limits,
    )
    reason, _ = attack.finish()
    text = attack.text()
    assert "wrote MB " in text, (reason, text)
    written = int(text.split("wrote MB ")[1].split()[0])
    assert written * MB <= limits.writable_bytes, text
    assert "No space left on device" in text
    assert reason == "ended: out of disk space (32 MB in all, 1 MB a file)", reason
    assert_still_serves()


def test_reads_outside_its_directory_and_forbidden_syscalls_fail(tmp_path: Path) -> None:
    registry_db = tmp_path / "registry.db"  # stands for the lab's data on this host
    registry_db.write_text("secret")
    registry_db.chmod(0o644)
    attack = Attack(
        f"""
import ctypes, os, socket
libc = ctypes.CDLL(None, use_errno=True)
class Snoop(Controller):
    def initialize(self, robot):
        for path in ("/etc/shadow", "/root", {str(registry_db)!r}):
            try:
                os.listdir(path) if os.path.isdir(path) else open(path).read()
                print("READ", path)
            except OSError as exc:
                print("denied", path, exc.strerror)
        for family in (socket.AF_INET, socket.AF_INET6, socket.AF_NETLINK, socket.AF_PACKET):
            try:
                socket.socket(family, socket.SOCK_RAW if family == socket.AF_PACKET else 0)
                print("SOCKET", family)
            except OSError as exc:
                print("no socket", int(family), exc.errno)
        for name, call in (("unshare", lambda: libc.unshare(0x10000000)),
                           ("ptrace", lambda: libc.ptrace(16, 1, 0, 0)),
                           ("personality", lambda: libc.personality(0x0040000)),
                           ("bpf", lambda: libc.syscall(321, 0, 0, 0)),
                           ("perf_event_open", lambda: libc.syscall(298, 0, 0, -1, -1, 0)),
                           ("keyctl", lambda: libc.syscall(250, 0, 0, 0, 0, 0)),
                           ("mount", lambda: libc.mount(b"none", b"/work", b"tmpfs", 0, None))):
            result = call()
            print("syscall", name, result, ctypes.get_errno())
        pids = sorted(int(p) for p in os.listdir("/proc") if p.isdigit())
        print("pids", pids)
    def do_work(self, robot):
        pass
""",
        slot=60.0,
    )
    wait_for(lambda: "pids " in attack.text(), 30, "the controller's snooping")
    attack.stop()
    text = attack.text()
    assert "READ" not in text and "SOCKET" not in text, text
    assert "no socket 2 97" in text  # AF_INET: EAFNOSUPPORT from the filter
    for name in ("unshare", "ptrace", "personality", "bpf", "perf_event_open", "keyctl", "mount"):
        assert f"syscall {name} -1 1" in text, (name, text)  # -1, EPERM
    pids = ast.literal_eval(text.split("pids ")[1].splitlines()[0])  # never eval its output
    assert len(pids) <= 4 and max(pids) < 10, f"host processes visible: {pids}"
    assert_still_serves()


def _sandbox_pythons(root: int) -> list[psutil.Process]:
    try:
        found = psutil.Process(root).children(recursive=True)
    except psutil.Error:
        return []
    return [p for p in found if p.name().startswith("python3")]


def test_a_busy_loop_and_a_fork_bomb_get_only_their_cpu_share() -> None:
    share = cpu_share(SandboxLimits().cpu_share)
    attack = Attack(
        """
import ast
import os
class Burn(Controller):
    def initialize(self, robot):
        for _ in range(6):
            try:
                os.fork()
            except OSError:
                pass
        while True:
            pass
    def do_work(self, robot):
        pass
""",
        slot=60.0,
    )
    proc = attack.sandbox.process
    assert proc is not None
    wait_for(lambda: len(_sandbox_pythons(proc.pid)) >= 4, 30, "the forks to start")

    def cpu_seconds() -> float:
        total = 0.0
        for p in _sandbox_pythons(proc.pid):
            try:
                times = p.cpu_times()
                total += times.user + times.system
            except psutil.Error:
                pass
        return total

    first, began = cpu_seconds(), time.monotonic()
    threading.Event().wait(1.5)  # a measuring window, not a wait for a condition
    used = (cpu_seconds() - first) / (time.monotonic() - began)
    niceness = {p.nice() for p in _sandbox_pythons(proc.pid)}
    took = attack.stop()
    assert niceness == {19}
    if share.mode != NICE_ONLY:
        assert used < SandboxLimits().cpu_share + 0.25, f"{used:.2f} cores with {share.mode}"
    # The grace, then the kill: the busy forks cannot hold the stop up.
    assert attack.sandbox.exit_reason == "stopped by the runner"
    assert took < 5.0
    assert_still_serves()


def test_a_memory_bomb_is_told_why_it_ended() -> None:
    attack = Attack(
        """
class Hog(Controller):
    def do_work(self, robot):
        hoard = []
        while True:
            hoard.append(bytearray(20 * 1024 * 1024))
""",
        slot=60.0,
        limits=SandboxLimits(memory_bytes=128 * MB),
    )
    reason, _ = attack.finish()
    assert reason == "ended: out of memory (the limit is 128 MB)"
    assert_still_serves()


def test_the_sandbox_leaves_no_cgroup_behind() -> None:
    base = cpu_share(SandboxLimits().cpu_share).base
    if base is None:
        pytest.skip("no cpu cgroup here")
    assert_still_serves()
    wait_for(lambda: not any(p.is_dir() for p in base.iterdir()), 5, "cgroups removed")
    assert os.path.isdir(base)


def test_a_run_that_uses_up_its_cpu_time_is_told_so() -> None:
    attack = Attack(
        """
class Spin(Controller):
    def do_work(self, robot):
        while True:
            pass
""",
        slot=60.0,
        limits=SandboxLimits(cpu_seconds=1),
    )
    reason, _ = attack.finish()
    assert reason == "killed: it used up its CPU time (1 s)", reason
    assert_still_serves()
