"""The one lab starter of the tests and the benchmarks.

Two shapes of lab, both started here and nowhere else:

- :class:`ProcessLab`: a router, then the services a test needs, one real
  ``wart`` process each, started with the command lines the lab itself uses
  (services/lab/wiring.py builds them, as for ``wart up`` and ``wart host``),
  so a test exercises the lab's real wiring, not a copy of it;
- :class:`UpLab`: a whole ``wart up`` in a subprocess (smoke and browser tests).

Every process runs on 127.0.0.1 on a free port with multicast scouting off,
and is stopped (then killed, if it must be) when its owner stops the lab: the
processes themselves, and the router, are tests/kit/procs.py's.
"""

from __future__ import annotations

import functools
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import nacl.pwhash
import psutil
import zenoh

from common import keys
from common.auth import RegistryIdentity, create_identity_key
from common.client.lab_client import LabClient
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import AuditEntry, AuditQuery
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab import wiring
from services.lab.lab_maps import SHIPPED_MAPS
from services.lab.labfile import ArenaSettings
from services.lab.supervisor import ChildSpec, start_wart
from services.lab.wiring import Wiring, up_args
from services.registry import accounts_db
from services.registry.accounts_db import RegistryDB, hash_password
from tests.kit.procs import REPO, Proc, Procs, Router, free_port, wait_alive, wart, wart_env

PASSWORD = "correct horse"
USERS = {"alice": "student", "bob": "student", "carol": "student", "ida": "instructor"}


# --- a lab started process by process --------------------------------------------------


# The test labs' first wait after a source's free failed logins (the lab's default
# is 2 s): a test that checks a source is slowed must never see the wait pass
# between two of its logins, which a busy machine can spend 2 s on.
LOGIN_WAIT = 60.0


@dataclass
class ProcessLab:
    """A router and the services a test starts, each with the lab's own command line."""

    router: Router
    procs: Procs
    state: Path
    identity: RegistryIdentity
    registry: Proc | None = None

    @property
    def realm(self) -> str:
        return self.router.realm

    @property
    def db_path(self) -> Path:
        return self.state / "registry.db"

    @property
    def key_hex(self) -> str:
        return self.identity.verify_key.hex()

    def options(self) -> NetworkOptions:
        """What every service of this lab gets: the router, the pinned registry key."""
        return self.router.options(registry_key=self.key_hex)

    def net_args(self) -> list[str]:
        return self.options().as_args()

    def wiring(self) -> Wiring:
        """This lab's host for services/lab/wiring.py: keys and maps in the state directory."""
        return Wiring(
            realm=self.realm,
            host="test",
            state_dir=self.state,
            net_args=lambda _role: self.net_args(),
            identity=lambda account: self.state / f"{account}.key",
            registry_key_file=self.state / "registry.key",
            map_dirs=(self.state / "maps", SHIPPED_MAPS),
            runner="runner",
            arena=ArenaSettings(),
        )

    def account(self, name: str) -> Path:
        """A service account (role ``service``) and its identity key, made once."""
        key_file = self.wiring().identity(name)
        if not key_file.exists():
            key = create_identity_key(key_file)
            db = RegistryDB(self.db_path)
            db.add_user(name, ["service"], public_key=bytes(key.verify_key))
            db.close()
        return key_file

    def start(
        self,
        spec: ChildSpec,
        *,
        name: str | None = None,
        extra: Sequence[str] = (),
        env: dict[str, str] | None = None,
    ) -> Proc:
        """One process of the plan, started and waited for (its token), as a supervisor does."""
        if spec.prepare is not None:
            spec.prepare()
        proc = self.procs.start(name or spec.name.replace(" ", "-"), [*spec.argv, *extra], env=env)
        if spec.alive_key is not None:
            wait_alive(self.router.options(), spec.alive_key, proc)
        return proc

    def wait_alive(self, kind: AliveKind, ident: str, proc: Proc) -> None:
        wait_alive(self.router.options(), keys.alive(self.realm, kind, ident), proc)

    # -- the services tests use

    def start_registry(self) -> Proc:
        """The registry, its login throttle's first wait :data:`LOGIN_WAIT`."""
        spec = wiring.registry_spec(self.wiring(), login_wait=LOGIN_WAIT)
        self.registry = self.start(spec)
        return self.registry

    def start_room(self, room: str, *extra: str) -> Proc:
        w = self.wiring()
        self.account(wiring.service_account("chat", room))
        return self.start(wiring.chat_room_spec(w, room), name=f"room-{room}", extra=extra)

    def start_engine(
        self,
        map_name: str = "foraging",
        *,
        world: str = "w1",
        identity: bool = False,
        seed: int = 3,
        extra: Sequence[str] = (),
        env: dict[str, str] | None = None,
    ) -> Proc:
        """The engine of ``world`` on a copy of a shipped map; with ``identity`` it logs in
        (``engine-WORLD``: agent contexts grant it MAC leases)."""
        w = self.wiring()
        w.maps_dir.mkdir(parents=True, exist_ok=True)
        map_path = w.maps_dir / f"{map_name}.json"
        map_path.write_bytes((SHIPPED_MAPS / f"{map_name}.json").read_bytes())
        if identity:
            self.account(wiring.service_account("engine", world))
        spec = wiring.engine_spec(w, world, map_path, seed=seed, login=identity)
        return self.start(spec, name="engine", extra=extra, env=env)

    def start_runner(self, name: str = "runner", account: str = "runner-svc") -> Proc:
        self.account(account)
        return self.start(wiring.runner_spec(self.wiring(), name, account=account), name="runner")

    def start_grader(self, *extra: str, name: str = "grader") -> Proc:
        """The grader (its service account made first, once)."""
        self.account(wiring.service_account("grader", "grader"))
        return self.start(wiring.grader_spec(self.wiring()), name=name, extra=extra)

    def start_agent_context(
        self,
        *extra: str,
        ctx: str = "arena",
        world: str = "w1",
        slot: float = 2.5,
        owner: str = "ida",
        account: str | None = None,
    ) -> Proc:
        """The agent context ``ctx`` of ``world`` (account ``ctx-CTX`` unless given)."""
        account = account or wiring.service_account("agent", ctx)
        self.account(account)
        spec = wiring.agent_context_spec(
            self.wiring(), ctx, world, owner=owner, slot_seconds=slot, account=account
        )
        name = "agent-context" if ctx == "arena" else f"agent-context-{ctx}"
        return self.start(spec, name=name, extra=extra)

    # -- clients

    @contextmanager
    def client(self, user: str | None = None, password: str = PASSWORD) -> Iterator[LabClient]:
        session = open_session(self.router.options(), wait=10.0)
        try:
            with LabClient(session, self.realm, self.identity.verify_key) as client:
                if user is not None:
                    client.login(user, password)
                yield client
        finally:
            close_session(session)

    def zsession(self) -> zenoh.Session:
        return open_session(self.router.options(), wait=10.0)

    def admin_wart(self, *args: str) -> subprocess.CompletedProcess[str]:
        """``wart ARGS`` as this lab's admin on its network (the password in WART_PASSWORD)."""
        net = ["--user", "admin", *self.net_args()]
        return wart(*args, *net, timeout=60.0, env={"WART_PASSWORD": PASSWORD})


@functools.cache
def _password_hash(password: str, quick: bool) -> bytes:
    """One argon2id hash of ``password`` per test session.

    A salted hash string verifies whichever account holds it, so every lab's
    accounts can share it; make_lab otherwise hashed six passwords per test.
    ``quick``: at libsodium's least cost. The registry checks a hash at the cost
    written in it, through the same argon2id call, so a test's login is the
    production path at about 0.1 ms instead of 65 (a suite's hundreds of logins
    cost its registries a minute of CPU), as Django's tests swap in a fast hasher;
    the benchmarks that time logins keep the registry's cost (bench/labproc.py).
    """
    if not quick:
        return hash_password(password)
    if len(password) < accounts_db.MIN_PASSWORD:
        return hash_password(password)  # refused, as the registry's own would be
    return bytes(
        nacl.pwhash.argon2id.str(
            password.encode(),
            opslimit=nacl.pwhash.argon2id.OPSLIMIT_MIN,
            memlimit=nacl.pwhash.argon2id.MEMLIMIT_MIN,
        )
    )


def lab_state(
    state: Path,
    *,
    users: dict[str, str] = USERS,
    password: str = PASSWORD,
    quick_passwords: bool = True,
) -> RegistryIdentity:
    """A lab's state before any process: the registry's key, and a DB with ``admin``
    (password PASSWORD) and ``users`` (a role each, password ``password``), their
    password hashes quick unless ``quick_passwords`` is False (see _password_hash)."""
    state.mkdir(parents=True, exist_ok=True)
    identity, _ = RegistryIdentity.load_or_create(state / "registry.key")
    db = RegistryDB(state / "registry.db")
    with mock.patch.object(
        accounts_db, "hash_password", functools.partial(_password_hash, quick=quick_passwords)
    ):
        # the admin ensure_admin would make, with a known password rather than a random one
        db.add_user("admin", ["admin"], password=PASSWORD)
        for name, role in users.items():
            db.add_user(name, [role], password=password)
    db.close()
    return identity


def make_lab(
    router: Router,
    procs: Procs,
    tmp: Path,
    *,
    users: dict[str, str] = USERS,
    password: str = PASSWORD,
) -> ProcessLab:
    """A lab on ``router`` with its state in TMP/state (see lab_state); no service started."""
    state = tmp / "state"
    identity = lab_state(state, users=users, password=password)
    return ProcessLab(router=router, procs=procs, state=state, identity=identity)


def registry_lab(router: Router, procs: Procs, tmp: Path) -> ProcessLab:
    """A lab (see make_lab) with its registry started."""
    lab = make_lab(router, procs, tmp)
    lab.start_registry()
    return lab


@contextmanager
def module_lab(router: Router, tmp: Path, *, users: dict[str, str] = USERS) -> Iterator[ProcessLab]:
    """A lab (see make_lab) whose processes are all stopped when the block ends: one
    lab for a whole test module, its state and logs under ``tmp``."""
    procs = Procs(tmp)
    try:
        yield make_lab(router, procs, tmp, users=users)
    finally:
        procs.stop_all()


# --- a whole `wart up` ---------------------------------------------------------------------


@dataclass
class UpLab:
    """A whole ``wart up`` lab in a subprocess, for smoke and browser tests."""

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

    def start(self) -> UpLab:
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


__all__ = [
    "PASSWORD",
    "USERS",
    "ProcessLab",
    "UpLab",
    "lab_state",
    "make_lab",
]


def audit_trail(admin: LabClient, **filters: object) -> list[AuditEntry]:
    """The registry's audit entries an admin reads, filtered as ``AuditQuery`` takes them."""
    entries, _ = admin.audit_trail(AuditQuery(**filters))  # type: ignore[arg-type]
    return entries


def session_revoked(client: LabClient) -> bool:
    """Whether the registry refuses ``client``'s session as revoked (asked with a request
    that needs one)."""
    try:
        client.directory()
    except LabError as exc:
        return "revoked" in str(exc)
    return False
