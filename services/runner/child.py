"""The program that runs inside the sandbox: loads one uploaded controller and runs it.

Standard library only (the sandbox offers Debian's python3 and nothing else).
It has no Zenoh session, no keys and no lease: the trusted parent relays
robot state on stdin and reads commands from the file descriptor given as
its first argument, one line each way, the messages of
common/controller/pipe.py. The student's prints and tracebacks go to
stdout/stderr, which the parent shows as the controller's output.

    python3 -I -S child.py CMD_FD CONTROLLER_FILE [lockstep | hang=SECONDS] [nproc=N]
    python3 -I -S child.py CMD_FD GRADER_FILE grade hang=SECONDS [nproc=N]

``nproc=N``: the sandbox's process limit, set here first thing (a runner that is not
root cannot set it from outside: services/runner/sandbox.py says why).

``grade`` (a teacher's grader, docs/COURSES.md): the file is not a controller
but defines ``grade(episode)``; it is called once with the episode's data
(``episode.json`` beside the file) and its dict goes back as ``pipe.Metrics``.
A grade() still running after ``hang`` seconds is told where it was (``pipe.Hung``).

``lockstep`` (a dry run): no clock of its own. Each state the parent sends
is one tick of a private simulated world; the controller's ``do_work`` runs
whenever the state's simulated time reaches its next period, and every state
is answered with ``pipe.Step`` after the commands it caused, so the parent
steps its world as fast as the controller answers.

A do_work that does not return is told where it was: asked by ``pipe.Probe`` just
before its slot ends (or, with ``hang=SECONDS``, by a watchdog once do_work has run
that long), the reader thread looks at the main thread's stack
(``sys._current_frames``) and sends ``pipe.Hung`` with the line and function of the
controller's own file it was in. The parent then ends the run and says so.
"""

from __future__ import annotations

import os
import resource
import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any


def main() -> int:
    cmd_fd = int(sys.argv[1])
    path = sys.argv[2]
    lockstep = "lockstep" in sys.argv[3:]
    grading = "grade" in sys.argv[3:]
    hang_after = 0.0
    for arg in sys.argv[3:]:
        if arg.startswith("hang="):
            hang_after = float(arg[len("hang=") :])
        elif arg.startswith("nproc="):  # before any thread or the controller starts
            most = int(arg[len("nproc=") :])
            resource.setrlimit(resource.RLIMIT_NPROC, (most, most))
    # The sandbox's copy of the controller API (stage.py) is importable only from here on.
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "lib"))
    from common.controller import (
        ControllerLoop,
        Khepera,
        KheperaState,
        RobotCommand,
        load_controller,
        pipe,
    )

    out = os.fdopen(cmd_fd, "wb", buffering=0)
    out_lock = threading.Lock()

    def tell(message: pipe.FromChild) -> None:
        with out_lock:
            out.write(pipe.encode(message))

    class PipeLink:
        def __init__(self) -> None:
            self.state = KheperaState()
            self.lock = threading.Lock()

        def latest(self) -> KheperaState:
            with self.lock:
                return self.state

        def send(self, command: RobotCommand) -> None:
            tell(pipe.Command(command))

    if grading:
        return run_grader(path, tell, hang_after)
    link = PipeLink()
    if lockstep:
        return run_lockstep(path, link, tell)
    stop = threading.Event()
    have_state = threading.Event()
    watch = HangWatch(path, threading.get_ident(), tell)

    def read_parent() -> None:
        for line in sys.stdin:
            try:
                message = pipe.decode_to_child(line)
            except pipe.PipeError as exc:
                print(f"[sandbox] ignored a bad line from the runner: {exc}", file=sys.stderr)
                continue
            if isinstance(message, pipe.Stop):
                break
            if isinstance(message, pipe.Probe):
                watch.report(pipe.HUNG_AFTER_S)
                continue
            with link.lock:
                link.state = message.state
            have_state.set()
        stop.set()

    threading.Thread(target=read_parent, daemon=True).start()

    try:
        controller = load_controller(path)
    except BaseException:
        tell(pipe.Failed(traceback.format_exc(limit=5)))
        return 3

    tell(pipe.Ready(type(controller).__name__))
    have_state.wait(5.0)
    watch.wrap(controller)
    if hang_after > 0:
        threading.Thread(target=watch.watchdog, args=(hang_after,), daemon=True).start()
    loop = ControllerLoop(controller, Khepera(link), stop=stop)
    try:
        loop.run()
    except BaseException as exc:
        if isinstance(exc, MemoryError):
            # The traceback keeps the controller's frames, and with them all it hoarded:
            # let that go first, or saying why could itself run out of memory.
            traceback.clear_frames(exc.__traceback__)
        text = traceback.format_exc(limit=5)
        sys.stderr.write(text)
        tell(pipe.Failed(text))
        return 4
    tell(pipe.Done(loop.iterations))
    return 0


class HangWatch:
    """When do_work started, if it is running, and where the main thread is in it."""

    def __init__(self, path: str, main_thread: int, tell: Callable[[Any], None]) -> None:
        self.path = path
        self.main_thread = main_thread
        self.tell = tell
        self.since: float | None = None  # time.monotonic() do_work was entered
        self.told = False

    def wrap(self, controller: Any) -> None:
        """Time each do_work call (an instance attribute over the class's method)."""
        do_work = controller.do_work

        def timed(robot: Any) -> Any:
            self.since = time.monotonic()
            try:
                return do_work(robot)
            finally:
                self.since = None

        controller.do_work = timed

    def where(self) -> tuple[int, str]:
        """(line, function) of the innermost frame of the controller's file; (0, "") if none."""
        frame = sys._current_frames().get(self.main_thread)
        while frame is not None:
            if frame.f_code.co_filename == self.path:
                return frame.f_lineno, frame.f_code.co_name
            frame = frame.f_back
        return 0, ""

    def report(self, after: float) -> bool:
        """Tell the runner do_work hangs if it has run ``after`` seconds; True if told."""
        from common.controller import pipe  # the sandbox's copy: on sys.path once main() ran

        since = self.since
        if since is None or self.told:
            return False
        seconds = time.monotonic() - since
        if seconds < after:
            return False
        line, function = self.where()
        self.told = True
        self.tell(pipe.Hung(round(seconds, 1), line, function))
        return True

    def watchdog(self, after: float) -> None:
        while not self.told:
            self.report(after)
            time.sleep(min(0.25, after / 4))


def run_lockstep(path: str, link: Any, tell: Callable[[Any], None]) -> int:
    """Step the controller once per state read, on the states' simulated clock."""
    from common.controller import Khepera, load_controller, pipe  # the sandbox's copy, as above

    try:
        controller = load_controller(path)
        period = float(controller.period)
        if not 0.001 <= period <= 10.0:
            raise ValueError(f"period {period} s is outside 0.001..10 s")
    except BaseException:
        tell(pipe.Failed(traceback.format_exc(limit=5)))
        return 3
    tell(pipe.Ready(type(controller).__name__))
    robot = Khepera(link)
    next_tick: float | None = None
    steps = 0
    try:
        for line in sys.stdin:
            message = pipe.decode_to_child(line)
            if isinstance(message, pipe.Stop):
                break
            if isinstance(message, pipe.Probe):
                continue
            link.state = message.state
            now = link.state.time
            if next_tick is None:
                controller.initialize(robot)
                next_tick = now
            if now + 1e-9 >= next_tick:
                controller.do_work(robot)
                steps += 1
                next_tick += period
                if next_tick <= now:  # a period shorter than a tick: once per tick
                    next_tick = now + period
            tell(pipe.Step(steps))
        controller.cleanup(robot)
    except BaseException:
        tell(pipe.Failed(traceback.format_exc(limit=5)))
        return 4
    tell(pipe.Done(steps))
    return 0


def run_grader(path: str, tell: Callable[[Any], None], hang_after: float) -> int:
    """Load the teacher's file, call its grade() once on the episode, send what it returned."""
    # The sandbox's copy, as above; json only for a teacher's grader run.
    import json

    from common.controller import pipe

    try:
        with open(os.path.join(os.path.dirname(path), "episode.json"), encoding="utf-8") as f:
            episode = json.load(f)
        namespace: dict[str, Any] = {"__name__": "grader", "__file__": path}
        with open(path, encoding="utf-8") as f:
            code = compile(f.read(), path, "exec")
        exec(code, namespace)  # the teacher's file, in the sandbox like a student's
        grade = namespace.get("grade")
        if not callable(grade):
            raise TypeError("the grader file defines no grade(episode) function")
        watch = HangWatch(path, threading.get_ident(), tell)
        if hang_after > 0:
            threading.Thread(target=watch.watchdog, args=(hang_after,), daemon=True).start()
        watch.since = time.monotonic()
        result = grade(episode)
        watch.since = None
        values = pipe.check_metrics(result)
    except pipe.PipeError as exc:  # what it returned is wrong, not where: no traceback
        tell(pipe.Failed(str(exc)))
        return 4
    except BaseException:
        tell(pipe.Failed(traceback.format_exc(limit=5)))
        return 4
    tell(pipe.Metrics(values))
    tell(pipe.Done(1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
