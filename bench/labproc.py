"""A router, a registry and a chat room as real processes for the benchmarks.

The processes are started by tests/kit/lab.py, the one lab starter of the tests and
the benchmarks (with the lab's own command lines, from services/lab/wiring.py);
this is its shape for benchmarks that start and stop a lab by hand, with the
children's logs kept quiet (``WART_BENCH_LOG_LEVEL``, default WARNING).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from common import keys
from common.keys import AliveKind
from common.zconfig import NetworkOptions
from tests.kit.forkserver import Running
from tests.kit.lab import ProcessLab, lab_state
from tests.kit.procs import Procs, start_router, wait_alive

REPO = Path(__file__).resolve().parent.parent


class BenchLab:
    def __init__(self, users: list[str], password: str) -> None:
        self.tmp = Path(tempfile.mkdtemp(prefix="wart-bench-"))
        self.realm = "bench"
        # The DB exists before the lab starts: a benchmark may add its own accounts first.
        # Its accounts' passwords at the registry's own cost: these benchmarks time logins.
        self.identity = lab_state(
            self.tmp,
            users=dict.fromkeys(users, "student"),
            password=password,
            quick_passwords=False,
        )
        self._procs = Procs(
            self.tmp, env={"WART_LOG_LEVEL": os.environ.get("WART_BENCH_LOG_LEVEL", "WARNING")}
        )
        self.lab: ProcessLab | None = None

    def _lab(self) -> ProcessLab:
        if self.lab is None:
            raise RuntimeError("the bench lab is not started (BenchLab.start)")
        return self.lab

    @property
    def port(self) -> int:
        return self._lab().router.port

    @property
    def options(self) -> NetworkOptions:
        """A client's network options (the router; no registry key)."""
        return self._lab().router.options()

    @property
    def procs(self) -> list[Running]:
        """The processes started, in order (the router first)."""
        return [proc.popen for proc in self._procs.started]

    def net(self) -> list[str]:
        return self._lab().net_args()

    def spawn(self, args: list[str], alive: tuple[AliveKind, str]) -> None:
        """``wart ARGS`` (a benchmark's own process), waited for until ``alive`` is seen."""
        proc = self._procs.start(alive[1], args)
        wait_alive(self.options, keys.alive(self.realm, *alive), proc)

    def start_router(self) -> None:
        """The router alone (a benchmark that runs its world in-process needs no registry)."""
        router = start_router(self._procs, self.realm, name="r")
        self.lab = ProcessLab(router, self._procs, state=self.tmp, identity=self.identity)

    def start(self, room_args: list[str] | None = None) -> None:
        """The router and the registry; with ``room_args``, the chat room ``room`` too."""
        self.start_router()
        self._lab().start_registry()
        if room_args is not None:
            self._lab().start_room("room", *room_args)

    def stop(self) -> None:
        self._procs.stop_all()


__all__ = ["REPO", "BenchLab"]
