"""Running an uploaded controller, which we do not trust, in a sandbox.

Layers, outermost first (each one alone would not be enough):

0. A cpu cgroup with a quota of part of one core, and nice 19
   (:mod:`services.runner.cpushare`; nice alone where no cgroup can be made).
1. ``setpriv`` drops to an unprivileged uid/gid when the runner is root: the
   kernel ignores RLIMIT_NPROC for root, so without this a fork bomb is free.
2. ``prlimit`` sets CPU time, address space, processes, open files and file size.
3. ``bwrap --unshare-all`` gives new user, pid, network, IPC and UTS
   namespaces: no network at all, a /proc of its own processes only, and a
   file system of read-only /, /usr and /dev plus size-limited tmpfs /work,
   /tmp and /dev/shm (together a quarter of the memory limit, taken off the
   address space). No /root, no
   /home, no keys, no Zenoh session.
4. A seccomp filter (:mod:`services.runner.syscalls`) refuses namespaces,
   mounts, ptrace, BPF, perf, keyrings, io_uring and non-AF_UNIX sockets.
5. A wall-clock kill at the end of the slot, from a timer that shares no pipe
   and no lock with the child, of its whole pid namespace.

Nothing the child does can block or grow the runner: writes to it are
non-blocking (a state it does not read in time is dropped), reads from it are
in bounded chunks (long lines cut), and printing faster than
``output_bytes_per_second`` ends the run as an output flood.

The child is Debian's ``/usr/bin/python3`` running services/runner/child.py
with only the standard library and common/controller/. It talks to this
parent over pipes, one JSON object per line, typed by common/controller/pipe.py;
every line it sends is checked (``pipe.decode_from_child``) before anything
reaches a robot, and a line that is not a message is refused, logged and
counted while the run goes on.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import psutil

from common import controller as controller_api
from common.controller import pipe
from common.controller.pipe import MAX_LINE_BYTES
from common.controller.upload_gate import MAX_SOURCE_BYTES, PrecheckError, precheck
from services.runner.pipes import RateBudget, read_lines, write_nowait
from services.runner.sandbox_host import (
    _give_uid,
    _take_uid,
    cpu_share,
    release_cpu_share,
    sandbox_problem,
    syscall_filter,
)
from services.runner.stage import MEMINFO, SandboxLimits, stage_files
from services.runner.syscalls import SANDBOX_PYTHON

log = logging.getLogger("wart.runner.sandbox")

# sandbox_problem and the CPU share are the host's (sandbox_host.py); callers find them here.
__all__ = [
    "MAX_SOURCE_BYTES",
    "PrecheckError",
    "Sandbox",
    "SandboxLimits",
    "cpu_share",
    "precheck",
    "release_cpu_share",
    "sandbox_problem",
]

MAX_OUTPUT_LINE_BYTES = 1000
# The first refused line of a run is logged, then one in this many: a hostile child
# writes as fast as it can, and the runner's log must not grow with it.
REFUSALS_LOGGED_EVERY = 1000


PROBE_AHEAD_S = 1.0
"""How long before the slot's end the child is asked whether do_work is stuck.

A stuck one is ended then, with where it was, so the agent context hears "hung: ..."
from the runner before its own clock would say "its slot ended". It loses the last
second of a slot it spent stuck anyway; a controller that is not stuck loses nothing."""


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
        on_step: Callable[[], None] | None = None,
        grade_input: bytes | None = None,
    ) -> None:
        """``on_step``: a dry run (the child in lockstep, services/runner/dryrun.py); it is
        called each time the child has answered one state. ``grade_input``: the source is a
        teacher's grader, run once on this episode data (services/runner/grader_run.py)."""
        self.grade_input = grade_input
        self.metrics: dict[str, float] | None = None  # what a grader's grade() returned
        self.controller_name = filename if grade_input is not None else precheck(source, filename)
        self.filename = filename
        problem = sandbox_problem()
        if problem:
            raise RuntimeError(f"cannot sandbox uploaded code: {problem}")
        self.source = source
        self.limits = limits or SandboxLimits()
        self.on_command = on_command
        self.on_output = on_output
        self.on_exit = on_exit
        self.on_step = on_step
        self.error_text = ""  # the traceback the controller raised, if it did
        self.rejected_commands = 0
        self.dropped_states = 0
        self.process: subprocess.Popen[bytes] | None = None
        self._stage: Path | None = None
        self._uid: int | None = None
        # The uid it ran as (root runners only), kept after the end: what to look
        # for when checking that nothing of it is left.
        self.uid: int | None = None
        self._cmd_read: int | None = None
        self._cpu = cpu_share(self.limits.cpu_share)
        self._cgroup = ""
        self._lock = threading.Lock()
        self._stdin_lock = threading.Lock()  # held only for non-blocking writes
        self._stopping = False
        self._stop_reason = ""
        self._exit_reason = ""
        self._done = threading.Event()
        # When each step of its end happened (time.monotonic()): an end that
        # came late says which step was slow.
        self.timeline: dict[str, float] = {}
        self._kill_timer: threading.Timer | None = None
        self._probe_timer: threading.Timer | None = None
        self._commands: threading.Thread | None = None

    # -- start

    def _stage_files(self) -> Path:
        return stage_files(self.source, self.limits, self.grade_input)

    def command_line(self, stage: Path, cmd_fd: int, seccomp_fd: int) -> list[str]:
        lim = self.limits
        self._cgroup = stage.name
        argv = self._cpu.prefix(self._cgroup)
        # RLIMIT_NPROC counts every process of a uid. A root runner gives each sandbox a
        # uid of its own and limits it from outside; a runner that is not root (a
        # container's user) shares its uid with itself and, in a pod, with the lab's
        # other services, and the same limit there refused the sandbox its namespaces
        # ("Creating new namespace failed"). The child then sets it inside, where the
        # kernel counts the processes of the sandbox's own user namespace.
        own_uid = os.geteuid() == 0
        if own_uid:
            self._uid = self.uid = _take_uid()
            argv += ["setpriv", f"--reuid={self._uid}", f"--regid={self._uid}", "--clear-groups"]
        # /work gets half of the writable space, /tmp and /dev/shm a quarter
        # each; / and /dev (bwrap's own tmpfs, of no set size) are read-only.
        work_bytes = lim.writable_bytes // 2
        tmp_bytes = lim.writable_bytes // 4
        argv += [
            "prlimit",
            # SIGXCPU at the soft limit says why; SIGKILL a second later if caught
            f"--cpu={lim.cpu_seconds}:{lim.cpu_seconds + 1}",
            f"--as={lim.address_space_bytes}",
            *([f"--nproc={lim.processes}"] if own_uid else []),
            f"--nofile={lim.open_files}",
            f"--fsize={lim.file_size_bytes}",
            "--",
            "bwrap",
            "--unshare-all",
            "--unshare-pid",  # in --unshare-all too: said here because /proc relies on it
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
            "--size",
            str(work_bytes),
            "--tmpfs",
            "/work",
            "--size",
            str(tmp_bytes),
            "--tmpfs",
            "/tmp",
            "--proc",
            "/proc",
            # The sandbox's memory, not the host's: a file made for its limits
            # (services/runner/stage.py), over the new /proc's meminfo.
            "--ro-bind",
            str(stage / MEMINFO),
            "/proc/meminfo",
            "--dev",
            "/dev",
            "--size",
            str(lim.writable_bytes - work_bytes - tmp_bytes),
            "--tmpfs",
            "/dev/shm",
            "--remount-ro",
            "/dev",
            "--remount-ro",  # bwrap's root is a tmpfs of no set size too
            "/",
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
            "--seccomp",
            str(seccomp_fd),
            "--",
            SANDBOX_PYTHON,
            "-I",
            "-S",
            "-u",
            "/ctl/child.py",
            str(cmd_fd),
            "/ctl/user/controller.py",
        ]
        if self.grade_input is not None:
            argv += ["grade", f"hang={lim.hang_seconds:g}"]
        elif self.on_step is not None:
            argv.append("lockstep")
        elif lim.hang_seconds > 0:
            argv.append(f"hang={lim.hang_seconds:g}")
        if not own_uid:
            argv.append(f"nproc={lim.processes}")
        return argv

    def start(self, slot_seconds: float) -> None:
        """Start the controller; it is killed ``slot_seconds`` from now at the latest."""
        self._stage = self._stage_files()
        cmd_read, cmd_write = os.pipe()
        filter_read, filter_write = os.pipe()
        self._cmd_read = cmd_read
        try:
            # A few hundred bytes: the pipe holds them all, bwrap reads them at start.
            os.write(filter_write, syscall_filter())
            os.close(filter_write)
            self.process = subprocess.Popen(
                self.command_line(self._stage, cmd_write, filter_read),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                pass_fds=(cmd_write, filter_read),
                start_new_session=True,
            )
        except OSError:
            os.close(cmd_read)
            self._cleanup_files()
            raise
        finally:
            os.close(cmd_write)
            os.close(filter_read)
        self.timeline["started"] = time.monotonic()
        assert self.process.stdin is not None
        os.set_blocking(self.process.stdin.fileno(), False)
        # The deadline first: nothing below can keep it from firing.
        self._kill_timer = threading.Timer(slot_seconds, self._slot_over)
        self._kill_timer.daemon = True
        self._kill_timer.start()
        probe = self.on_step is None and self.grade_input is None
        if probe and slot_seconds > PROBE_AHEAD_S + pipe.HUNG_AFTER_S:
            self._probe_timer = threading.Timer(slot_seconds - PROBE_AHEAD_S, self._probe)
            self._probe_timer.daemon = True
            self._probe_timer.start()
        self._commands = threading.Thread(
            target=self._read_commands, daemon=True, name="sandbox-cmd"
        )
        self._commands.start()
        threading.Thread(target=self._read_output, daemon=True, name="sandbox-out").start()
        threading.Thread(target=self._wait, daemon=True, name="sandbox-wait").start()

    # -- relaying

    def _write(self, line: bytes) -> bool | None:
        """True if written, False if the child's pipe is full, None if it is closed."""
        proc = self.process
        with self._stdin_lock:
            if proc is None or proc.stdin is None or proc.stdin.closed:
                return None
            try:
                return write_nowait(proc.stdin.fileno(), line)
            except (OSError, ValueError):
                return None

    def send_state(self, state: controller_api.KheperaState) -> bool:
        """Hand the newest robot state to the controller; False once it has gone.

        Never blocks: a controller that does not read its states loses them
        (the next one is newer anyway) and is told so once.
        """
        line = pipe.encode(pipe.State(state))
        if self.process is None or self.process.poll() is not None:
            return False
        written = self._write(line)
        if written is None:
            return False
        if not written:
            self.dropped_states += 1
            if self.dropped_states == 1:
                self._say("[runner] the controller is not reading its robot states: dropping them")
        return True

    def _read_commands(self) -> None:
        assert self._cmd_read is not None
        budget = RateBudget(self.limits.commands_per_second)
        try:
            for raw, cut in read_lines(self._cmd_read, MAX_LINE_BYTES):
                if cut:
                    self._refuse(f"a line over {MAX_LINE_BYTES} bytes", budget)
                    continue
                try:
                    message = pipe.decode_from_child(raw)
                except pipe.PipeError as exc:
                    self._refuse(str(exc), budget)
                    continue
                self._on_message(message, budget)
        finally:
            os.close(self._cmd_read)

    def _refuse(self, why: str, budget: RateBudget) -> None:
        """A line from the child that is not a message: counted, logged, and the run goes on.

        The student hears why while within the command rate (a flood of bad lines
        is counted only, like a flood of good ones).
        """
        self.rejected_commands += 1
        n = self.rejected_commands
        if n == 1 or n % REFUSALS_LOGGED_EVERY == 0:
            name = self.controller_name
            log.warning("controller %s: refused line %d of its pipe: %s", name, n, why)
        if budget.take():
            self._say(f"[runner] refused a message from the controller: {why}")

    def _on_message(self, message: pipe.FromChild, budget: RateBudget) -> None:
        if isinstance(message, pipe.Command):
            if budget.take():
                self.on_command(message.command)
            else:
                self.rejected_commands += 1
        elif isinstance(message, pipe.Step):
            if self.on_step is not None:
                self.on_step()
        elif isinstance(message, pipe.Ready):
            now = time.monotonic()
            self.timeline["ready"] = now
            took = now - self.timeline.get("started", now)
            # A busy host starts a sandbox slowly (its Python, the controller's imports):
            # the operator's log says how slowly, so a late first print has a cause.
            log.info("controller %s ready %.1f s after its sandbox began", message.controller, took)
            self._say(f"[runner] controller {message.controller} started")
        elif isinstance(message, pipe.Failed):
            text = message.message
            self.error_text = self.error_text or text
            self._exit_reason = self._stop_reason or self._failure_reason(text)
            for line in text.splitlines():
                self._say(line)
        elif isinstance(message, pipe.Hung):
            what = "grade()" if self.grade_input is not None else "do_work"
            reason = pipe.hung_reason(message, self.filename, what)
            log.info("controller %s: %s", self.controller_name, reason)
            self._end_now(reason)
        elif isinstance(message, pipe.Metrics):
            self.metrics = message.values
        elif isinstance(message, pipe.Done):
            self._exit_reason = self._stop_reason or "the controller finished"

    def _failure_reason(self, traceback_text: str) -> str:
        """Why the controller raised, in the student's terms where a limit did it."""
        mb = self.limits.memory_bytes >> 20
        if "MemoryError" in traceback_text:
            return f"ended: out of memory (the limit is {mb} MB)"
        if any(s in traceback_text for s in ("No space left on device", "File too large")):
            disk = self.limits.writable_bytes >> 20
            big = self.limits.file_size_bytes >> 20
            return f"ended: out of disk space ({disk} MB in all, {big} MB a file)"
        return "the controller raised an exception"

    def _read_output(self) -> None:
        proc = self.process
        assert proc is not None and proc.stdout is not None
        lim = self.limits
        lines = RateBudget(lim.output_lines_per_second)
        flood = RateBudget(lim.output_bytes_per_second, 4 * lim.output_bytes_per_second)

        def count(n: int) -> None:
            if not flood.take(n) and not self._stopping:
                kb = lim.output_bytes_per_second >> 10
                self._end_now(f"killed: output flood (over {kb} KB/s printed)")

        dropped = 0
        for raw, cut in read_lines(proc.stdout.fileno(), MAX_OUTPUT_LINE_BYTES, count):
            if lines.take():
                if dropped:
                    self._say(
                        f"[runner] {dropped} output lines dropped (over "
                        f"{lim.output_lines_per_second} lines/s)"
                    )
                    dropped = 0
                text = raw.decode("utf-8", "replace")
                if cut:
                    text += f" [runner: line cut at {MAX_OUTPUT_LINE_BYTES} bytes]"
                self._say(text)
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
        self.timeline["exited"] = time.monotonic()
        for timer in (self._kill_timer, self._probe_timer):
            if timer is not None:
                timer.cancel()
        if self._commands is not None:
            # Its last lines (a Hung, a Failed) are read before the reason is said.
            self._commands.join(1.0)
        if not self._exit_reason:
            if self._stopping:
                self._exit_reason = self._stop_reason
            elif code == -signal.SIGXCPU or code == 128 + signal.SIGXCPU:
                self._exit_reason = f"killed: it used up its CPU time ({self.limits.cpu_seconds} s)"
            elif code < 0 or code > 128:
                # bwrap passes a child's death by a signal on as 128 + signal
                number = -code if code < 0 else code - 128
                with contextlib.suppress(ValueError):
                    self._exit_reason = f"killed by {signal.Signals(number).name}"
                self._exit_reason = self._exit_reason or f"exited with code {code}"
            else:
                self._exit_reason = f"exited with code {code}"
        # Its stdout may still be held by a leftover grandchild: the group goes too.
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        with self._stdin_lock:
            if proc.stdin is not None:
                with contextlib.suppress(OSError):
                    proc.stdin.close()
        self._cleanup_files()
        self.timeline["cleaned up"] = time.monotonic()
        self._done.set()
        try:
            self.on_exit(self._exit_reason)
        except Exception:
            log.exception("exit callback failed")

    # -- stopping

    def _probe(self) -> None:
        """Near the slot's end: ask the child whether do_work is stuck (it says Hung if so)."""
        if not self._stopping:
            self._write(pipe.encode(pipe.Probe()))

    def _slot_over(self) -> None:
        self.stop(grace=0.5, reason="stopped at the end of its slot")

    def _first_stop(self, reason: str, how: str) -> bool:
        """Whether this is the run's first stop (``how``: "kill" or "stop", timed); a later
        one finds the run already ending, and its reason is not kept."""
        with self._lock:
            if self._stopping:
                return False
            self._stopping = True
            self._stop_reason = reason
        self.timeline[how] = time.monotonic()
        return True

    def _end_now(self, reason: str) -> None:
        """Kill at once for ``reason`` (called on a reader thread: the kill runs on its own)."""
        if not self._first_stop(reason, "kill"):
            return
        proc = self.process
        if proc is not None:
            threading.Thread(target=_kill_sandbox, args=(proc,), daemon=True).start()

    def stop(self, grace: float = 1.0, reason: str = "stopped") -> None:
        """Ask the controller to clean up, then kill its whole process group.

        Nothing here waits on the child's pipes: the stop message is written
        without blocking (lost if its pipe is full), the kill follows ``grace``
        seconds later whatever the child does.
        """
        if not self._first_stop(reason, "stop"):
            return
        proc = self.process
        if proc is None:
            return
        if proc.poll() is None:
            self._write(pipe.encode(pipe.Stop()))
            with self._stdin_lock:
                if proc.stdin is not None:
                    with contextlib.suppress(OSError):
                        proc.stdin.close()
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            if not self._exit_reason:
                self._exit_reason = reason
            self.timeline["kill"] = time.monotonic()
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
        if self._cgroup:
            self._cpu.release(self._cgroup)
            self._cgroup = ""
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
