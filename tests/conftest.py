"""Shared fixtures: a real Zenoh router on a free port, clients, and process helpers.

Every process a test starts runs on 127.0.0.1 with multicast scouting off, and
is stopped (then killed, if it must be) when the test ends. The processes are
started by tests/kit/lab.py, the one lab starter; its helpers and the kit's
wait_for are re-exported here for the tests that import them from this file.
"""

from __future__ import annotations

import functools
import logging
import os
import uuid
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from common import keys
from common.client import lab_client
from common.log import StderrHandler
from common.service import close_session, open_session
from services.lab.supervisor import AliveWatch
from services.runner.sandbox import sandbox_problem
from tests.checkout_guard import CheckoutGuard
from tests.kit import forkserver
from tests.kit.procs import REPO, Proc, Procs, Router, free_port, start_router, wart_env
from tests.kit.waits import wait_for
from tests.time_spent import PhaseCpu, TimeSpent

# Each client derives its mailbox key from the password (argon2id, about 77 ms of CPU)
# before it asks the registry. On a student's machine that is their own CPU; the tests
# log the same users of the same lab in again and again in one process, and on a busy
# machine a derivation can outlast the 2 s a slowed source must wait after its third
# failure. The key is a pure function of (realm, user, password): each is derived once
# per test process, and the registry's side is untouched.
lab_client.mailbox_key_from_password = functools.cache(lab_client.mailbox_key_from_password)

# The kit's `wart` processes are forked from one that has imported what they import
# (tests/kit/forkserver.py): hundreds of service starts, each without 0.4-0.7 s of imports.
os.environ.setdefault(forkserver.ENABLED_ENV, "1")

_SANDBOX_PROBLEM = sandbox_problem()
# For the tests that run controllers in the runner's real sandbox.
needs_sandbox = pytest.mark.skipif(
    _SANDBOX_PROBLEM is not None, reason=f"no sandbox: {_SANDBOX_PROBLEM}"
)


def pytest_configure(config: pytest.Config) -> None:
    # Where tests run (each worker, or the only process), each phase's CPU is measured;
    # on the controller only, the summary: workers' reports reach it.
    config.pluginmanager.register(PhaseCpu(), "phase_cpu")
    if not hasattr(config, "workerinput"):
        config.pluginmanager.register(TimeSpent(), "time_spent")
        config.pluginmanager.register(CheckoutGuard(), "checkout_guard")


# A test directory's kind is its marker (`-m "not browser"`), so no module forgets it.
_DIRECTORY_MARKS = {
    "integration": "integration",
    "containers": "integration",
    "browser": "browser",
    "smoke": "smoke",
}


def pytest_itemcollected(item: pytest.Item) -> None:
    kind = _DIRECTORY_MARKS.get(item.path.parent.name)
    if kind is not None:
        item.add_marker(kind)
    if item.get_closest_marker("one_worker") is not None:
        # The module's lab or router is a module fixture: on one worker it starts once.
        item.add_marker(pytest.mark.xdist_group(f"{item.path.parent.name}-{item.path.stem}"))
    # Under xdist (./dev test), the browser tests run in two groups, each one test at
    # a time on its own worker: each drives a Chromium rendering WebGL in software,
    # and all at once on two cores made each page slow for nothing; but as one group
    # they were the suite's critical path (9 of its 9.5 minutes). A module stays in
    # one group (its lab, a module fixture, is started once). The other tests, which
    # mostly wait on their processes, share the other workers.
    # Marked as each item is collected: xdist reads the groups into the node ids
    # in its own collection_modifyitems, and marked there (after it) they were
    # ignored and the browser tests spread over every worker.
    if "browser" in item.keywords or item.path.parent.name == "browser":
        half = zlib.crc32(item.path.name.encode()) % 2
        item.add_marker(pytest.mark.xdist_group(f"browser-{half}"))


@pytest.fixture(autouse=True)
def _logging_as_found() -> Iterator[None]:
    """A test that runs a command's main in this process (its setup_logging) leaves the
    root logger as it found it: otherwise every later test's in-process viewer and
    services log to the worker's own stderr, between the dots of the run's output."""
    root = logging.getLogger()
    before, level = set(root.handlers), root.level
    yield
    for handler in root.handlers[:]:
        if handler not in before and isinstance(handler, StderrHandler):
            root.removeHandler(handler)
    root.setLevel(level)


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    manager = Procs(tmp_path)
    yield manager
    manager.stop_all()


@pytest.fixture
def realm() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


@pytest.fixture
def router(request: pytest.FixtureRequest, procs: Procs, realm: str) -> Iterator[Router]:
    """A real ``wart router`` process on a free 127.0.0.1 port, multicast scouting off; in a
    module marked ``shared_router``, this test's own realm on the module's router instead."""
    if request.node.get_closest_marker("shared_router") is not None:
        module_router: Router = request.getfixturevalue("module_router")
        yield module_router.in_realm(realm)
        return
    # Stopped with the other processes at ``procs``' teardown, after every service this
    # test started on it (the reverse of their starts): a service stops as it does in a
    # lab, its goodbyes answered, not each waiting out a timeout with its router gone.
    yield start_router(procs, realm)


@pytest.fixture(scope="module")
def module_router(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Router]:
    """One ``wart router`` for a whole module. A router routes any realm and every key a
    test uses is under its realm, so a module whose tests neither stop nor restart their
    router may give each test its own realm on this one (about 2 s a test on a busy
    machine), marked ``shared_router``."""
    procs = Procs(tmp_path_factory.mktemp("router"))
    r = start_router(procs, f"t{uuid.uuid4().hex[:10]}")
    yield r
    procs.stop_all()


__all__ = ["REPO", "Proc", "Procs", "Router", "free_port", "wait_for", "wart_env"]


@pytest.fixture
def zsession(router: Router) -> Iterator[zenoh.Session]:
    """A Zenoh client session connected to the test router."""
    session = open_session(router.options(), wait=10.0)
    yield session
    close_session(session)


@pytest.fixture
def alive_watch(zsession: zenoh.Session, router: Router) -> Iterator[AliveWatch]:
    watch = AliveWatch(zsession, keys.alive_all(router.realm))
    yield watch
    watch.close()
