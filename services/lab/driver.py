"""The one supervisor driver behind ``wart up`` and ``wart host``.

Both run a host the same way: start its router (``wart up`` may join one
instead), open the supervisor's own session, watch the realm's liveliness
tokens, wait for the router, provision what the services need, start the
services wave by wave (each "up" when its token appears), serve hosting
(contexts on request, load reports), keep everything running until told to
stop, then stop it all in reverse order. Those steps are written once, in
:meth:`HostDriver.run`; a subclass says only what differs between a lab
file's host and the one-machine lab (its router, its session's options, its
plan, its hosting service, the lines the operator reads).
"""

from __future__ import annotations

import contextlib
import threading
from pathlib import Path

import zenoh

from common import keys
from common.keys import AliveKind
from common.log import log_to_file
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab.hosting import HostingService
from services.lab.supervisor import AliveWatch, Child, ChildSpec, Supervisor


def say(text: str) -> None:
    """One line for the operator; a closed terminal or pipe (``wart up | tee``,
    then Ctrl-C) must never interrupt an orderly stop."""
    with contextlib.suppress(BrokenPipeError, OSError):
        print(text, flush=True)


class HostDriver:
    """The steps of running one host under supervision; subclasses fill in what differs."""

    # wart host serves hosting (its load, its token) while its services start; wart up
    # opens its front door for contexts on request once its own lab serves.
    hosting_first = False
    # The in-process hosting service's own log (under STATE_DIR/logs, beside its children's).
    host_log = "host.log"

    def __init__(self, realm: str, state_dir: Path) -> None:
        self.realm = realm
        self.state_dir = state_dir

    # -- what differs (overridden)

    def banner(self) -> str:
        raise NotImplementedError

    def router(self) -> ChildSpec | None:
        """The router to start first; None: join an existing one (``network`` names it)."""
        raise NotImplementedError

    def network(self) -> NetworkOptions:
        """The supervisor's own session (it watches tokens and serves hosting)."""
        raise NotImplementedError

    def joined(self) -> str:
        """The line said when joining an existing router."""
        return "  joined the lab router"

    def provision(self) -> None:
        """What the services need before they start (keys, accounts); ValueError or OSError
        stops the start with its message."""

    def waves(self) -> list[list[ChildSpec]]:
        raise NotImplementedError

    def came_up(self, child: Child) -> None:
        """A child of the plan came up."""

    def hosting(self, session: zenoh.Session, supervisor: Supervisor) -> HostingService:
        """The hosting service, started."""
        raise NotImplementedError

    def adopt(self, hosting: HostingService, children: list[Child]) -> None:
        """Count the plan's own arenas in the hosting service's load (once all started)."""

    def running(self) -> str:
        raise NotImplementedError

    def stopping(self) -> str:
        raise NotImplementedError

    def stopped(self) -> str:
        raise NotImplementedError

    # -- the steps (written once)

    def run(self, stop: threading.Event, *, ready: threading.Event | None = None) -> int:
        """Start the host, keep it running until ``stop`` is set, then stop it all."""
        self.state_dir.mkdir(parents=True, exist_ok=True)
        supervisor = Supervisor(self.state_dir / "logs", say=say)
        # The hosting service runs in this process: its lines (refused requests, junk
        # from a fuzzer) go to its own file like every service's, not to the operator's
        # terminal, which keeps only its errors and the supervisor's words.
        log_to_file(f"wart.{AliveKind.HOST.value}", self.state_dir / "logs" / self.host_log)
        say(self.banner())
        session: zenoh.Session | None = None
        hosting: HostingService | None = None
        code = 0
        try:
            spec = self.router()
            router = supervisor.add(spec) if spec is not None else None
            if router is not None:
                supervisor.spawn(router)
            try:
                # Quiet while our own router starts: waiting for it is expected.
                session = open_session(self.network(), wait=30.0, quiet=router is not None)
            except ConnectionError as exc:
                say(f"  ✗ {exc}")
                return 1
            supervisor.watch = AliveWatch(session, keys.alive_all(self.realm))
            if router is not None and not supervisor.wait_ready(router):
                return 1
            if router is None:
                say(self.joined())
            try:
                self.provision()
            except (ValueError, OSError) as exc:
                say(f"  ✗ {exc}")
                return 1
            if self.hosting_first:
                hosting = self.hosting(session, supervisor)
            children: list[Child] = []
            for wave in self.waves():
                if stop.is_set():
                    break
                for child, up in supervisor.start_together(wave, on_up=self.came_up):
                    children.append(child)
                    if not up:
                        code = 1
            if hosting is None and not stop.is_set():
                # In this process (not a child): its spawned contexts are this
                # supervisor's children, restarted and stopped with the rest.
                hosting = self.hosting(session, supervisor)
            if hosting is not None:
                self.adopt(hosting, children)
            if not stop.is_set():
                say(self.running())
                if ready is not None:
                    ready.set()
                supervisor.run_until(stop)
        finally:
            say(self.stopping())
            if hosting is not None:
                hosting.stop()  # no new context starts while the children stop
            supervisor.stop_all()
            if session is not None:
                close_session(session)
            say(self.stopped())
        return code
