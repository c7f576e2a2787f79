"""Uploaded controllers run contained: limits hold, the parent keeps serving.

These run the real sandbox (setpriv, prlimit, bubblewrap, Debian's python3);
there is no Zenoh here: the runner service relays over these same pipes.
"""

from __future__ import annotations

import logging
import os
import queue
import textwrap
import time
from collections.abc import Callable

import psutil
import pytest

from common.controller import KheperaState, RobotCommand
from services.runner.sandbox import PrecheckError, Sandbox, SandboxLimits, precheck
from tests.conftest import needs_sandbox, wait_for

STATE = KheperaState(time=1.0, proximity=(0, 0, 900, 0, 0, 0, 0, 0))


class Run:
    """A sandbox with its commands and output collected.

    A test that needs the controller to have done something uses a long slot and
    :meth:`stop_when`: on a busy machine a short slot can end before the
    sandbox's Python has started, and the controller never runs at all.
    """

    def __init__(self, body: str, slot: float = 60.0, limits: SandboxLimits | None = None) -> None:
        source = textwrap.dedent(body).encode()
        self.commands: queue.Queue[dict] = queue.Queue()
        self.output: list[str] = []
        self.sandbox = Sandbox(
            source, limits=limits, on_command=self.commands.put, on_output=self.output.append
        )
        self.started = time.monotonic()
        self.started_wall = time.time()
        self.sandbox.start(slot)
        self.sandbox.send_state(STATE)

    def finish(self, timeout: float = 15.0) -> str:
        assert self.sandbox.wait(timeout), "the sandbox did not end"
        return self.sandbox.exit_reason

    def stop_when(self, condition: Callable[[], bool], what: str) -> str:
        """Stop the run once ``condition`` holds; the reason it ended."""
        wait_for(condition, 30, what)
        self.sandbox.stop(grace=0.5, reason="stopped by the test")
        return self.finish()

    def text(self) -> str:
        return "\n".join(self.output)


HEADER = "from common.controller import Controller, Khepera\n"


@needs_sandbox
def test_controller_reads_sensors_and_drives() -> None:
    run = Run(
        HEADER
        + """
class Avoid(Controller):
    period = 0.02
    def do_work(self, robot: Khepera) -> None:
        front = robot.proximity().values[2]
        print("front", front)
        robot.set_speeds(-5 if front > 500 else 10, 5)
""",
    )
    command = run.commands.get(timeout=30)
    assert command == RobotCommand(speeds=(-5, 5))
    assert run.stop_when(lambda: "front 900" in run.text(), "the controller's print") == (
        "stopped by the test"
    )
    assert "front 900" in run.text()
    assert "[runner] controller Avoid started" in run.text()


@needs_sandbox
def test_endless_loop_is_killed_at_the_end_of_its_slot() -> None:
    run = Run(
        HEADER
        + """
class Spin(Controller):
    def do_work(self, robot):
        while True:
            pass
""",
        slot=1.0,
    )
    reason = run.finish()
    assert time.monotonic() - run.started < 5.0
    assert "slot" in reason


@needs_sandbox
def test_proc_meminfo_shows_the_sandboxs_memory_not_the_hosts() -> None:
    limits = SandboxLimits(memory_bytes=192 << 20)
    run = Run(
        HEADER
        + """
class Meminfo(Controller):
    def initialize(self, robot):
        for line in open("/proc/meminfo"):
            if line.split(":")[0] in ("MemTotal", "MemFree", "MemAvailable", "SwapTotal"):
                print("mem", line.split()[0], line.split()[1])
        print("read")
    def do_work(self, robot):
        pass
""",
        limits=limits,
    )
    run.stop_when(lambda: "read" in run.output, "the controller to read /proc/meminfo")
    seen = dict(line.split()[1:3] for line in run.output if line.startswith("mem "))
    assert seen["MemTotal:"] == str(192 * 1024), run.text()  # the limit, in kB
    available = int(seen["MemAvailable:"])
    assert int(seen["MemFree:"]) == available == limits.address_space_bytes >> 10
    assert seen["SwapTotal:"] == "0"
    host_kb = psutil.virtual_memory().total >> 10
    assert host_kb > 192 * 1024  # the host has more: what the sandbox must not see


@needs_sandbox
def test_unbounded_allocation_fails_inside_the_sandbox() -> None:
    run = Run(
        HEADER
        + """
class Hog(Controller):
    def do_work(self, robot):
        hoard = []
        while True:
            hoard.append(bytearray(50 * 1024 * 1024))
""",
        limits=SandboxLimits(memory_bytes=200 * 1024 * 1024),
    )
    reason = run.finish(timeout=60)
    assert "MemoryError" in run.text()
    assert reason == "ended: out of memory (the limit is 200 MB)"


@needs_sandbox
def test_fork_bomb_is_contained_and_nothing_survives_the_slot() -> None:
    run = Run(
        HEADER
        + """
import os, time
class Bomb(Controller):
    def do_work(self, robot):
        for _ in range(500):
            try:
                os.fork()
            except OSError as exc:
                print("fork refused:", exc.errno)
                time.sleep(60)
""",
        limits=SandboxLimits(processes=8),
    )
    pid = run.sandbox.process.pid
    uid = run.sandbox.uid
    run.stop_when(lambda: "fork refused" in run.text(), "a fork to be refused")
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    # No live process of the sandbox's uid is left anywhere on the machine (a
    # zombie awaiting the container's init holds nothing). Its uid only: other
    # sandboxes (other tests, other runners) may be running meanwhile.
    if uid is not None:
        wait_for(lambda: not _live_processes_of(uid), 5.0, "sandbox processes to end")


def _live_processes_of(uid: int) -> list[int]:
    return [
        p.pid
        for p in psutil.process_iter(["uids", "status"])
        if p.info["uids"]
        and p.info["uids"].real == uid
        and p.info["status"] != psutil.STATUS_ZOMBIE
    ]


@needs_sandbox
def test_files_outside_and_the_network_are_out_of_reach() -> None:
    secret_dir = os.path.expanduser("~")
    run = Run(
        HEADER
        + f"""
import os, socket
class Snoop(Controller):
    def initialize(self, robot):
        for path in [{secret_dir!r}, "/etc/shadow", "/etc/passwd", {os.getcwd()!r}]:
            try:
                os.listdir(path) if os.path.isdir(path) else open(path).read()
                print("READ", path)
            except OSError as exc:
                print("denied", path, type(exc).__name__)
        try:
            socket.create_connection(("127.0.0.1", 7447), timeout=1)
            print("NETWORK OPEN")
        except OSError as exc:
            print("no network", type(exc).__name__)
        print("uid", os.getuid(), "cwd", os.getcwd(), os.listdir("."))
    def do_work(self, robot):
        pass
""",
    )
    run.stop_when(lambda: "uid " in run.text(), "the controller's snooping")
    text = run.text()
    assert "READ" not in text and "NETWORK OPEN" not in text, text
    assert "no network" in text and "cwd /work []" in text
    assert "uid 0 " not in text


@needs_sandbox
def test_bad_commands_are_refused_and_counted(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "wart.runner.sandbox")
    run = Run(
        HEADER
        + """
import os, sys
class Liar(Controller):
    def initialize(self, robot):
        fd = int(sys.argv[1])
        os.write(fd, b'not json\\n{"t":"cmd","speeds":[999,0]}\\n{"t":"cmd","format":"/"}\\n')
        robot.set_speeds(3, 4)
    def do_work(self, robot):
        pass
""",
    )
    # Refused with the reason, and the run goes on: the good command after them arrives.
    assert run.commands.get(timeout=30) == RobotCommand(speeds=(3, 4))
    run.stop_when(lambda: "unknown command fields" in run.text(), "the refusals said")
    assert run.sandbox.rejected_commands >= 3
    assert "refused a message from the controller: not JSON" in run.text()
    assert "cmd: speeds must be two integers" in run.text()
    assert "cmd: unknown command fields: format" in run.text()
    # The runner's log says it once (not once a line: the child chooses how many).
    refusals = [r for r in caplog.records if "refused line" in r.getMessage()]
    assert len(refusals) == 1 and "not JSON" in refusals[0].getMessage()


@pytest.mark.parametrize(
    ("source", "message"),
    [
        (b"def broken(:\n", "line 1: syntax error"),
        (b"x = 1\n", "defines no controller"),
        (b"\xff\xfe", "not UTF-8"),
        (b"#" * 70_000, "limited to"),
    ],
)
def test_precheck_explains_what_cannot_run(source: bytes, message: str) -> None:
    with pytest.raises(PrecheckError, match=message):
        precheck(source)
