"""``wart host --lab FILE --name HOST``: this machine's share of a multi-host lab.

Starts the host's Zenoh router (TLS, mutual TLS and the lab's access rules,
meshed with the routers of the hosts it lists), then the services the lab file
gives this host, under the same supervision as ``wart up`` (wait for each
liveliness token, restart with backoff, stop in reverse order). Publishes its
load on ``host/<host>/load`` and starts or stops arenas (an engine and its
agent context) on request on ``host/<host>/spawn`` from users
with the ``host`` permission. Adding a host to a lab is starting ``wart host``
on one more machine.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import psutil
import zenoh

from common import cli, keys
from common.auth import Verifier, parse_public_key
from common.keys import AliveKind
from common.labfile import LabFile, LabFileError, load
from common.messages import ErrorReply, MessageError, OkReply, decode, encode
from common.messages.host import (
    ArenaInfo,
    ArenaReply,
    HostLoad,
    LoadRequest,
    SpawnArena,
    StopArena,
)
from common.revocations import RevocationFeed
from common.service import RequestError, Service, close_session, open_session
from common.supervisor import AliveWatch, Child, Supervisor
from common.zconfig import NetworkOptions
from services.hostplan import (
    HostContext,
    arena_specs,
    check_available,
    host_plan,
    map_with_robots,
    read_registry_key,
    resolve_map,
    router_spec,
    write_configs,
)


@dataclass
class Arena:
    info: ArenaInfo
    children: list[Child] = field(default_factory=list)


class HostService(Service):
    """Load reports and arena placement for one host; the processes are the supervisor's."""

    kind = AliveKind.HOST

    def __init__(
        self,
        session: zenoh.Session,
        ctx: HostContext,
        supervisor: Supervisor,
        *,
        clock: object = time.time,
    ) -> None:
        super().__init__(session, ctx.realm, ctx.host.name)
        self.ctx = ctx
        self.lab: LabFile = ctx.lab
        self.supervisor = supervisor
        registry_key = parse_public_key(ctx.registry_key)
        self.verifier = Verifier(registry_key, ctx.realm)
        self._registry_key = registry_key
        self._feed: RevocationFeed | None = None
        self.arenas: dict[str, Arena] = {}
        self._lock = threading.Lock()
        self._spawn_lock = threading.Lock()  # one arena start at a time on a host
        self._load_thread: threading.Thread | None = None
        self._latest: HostLoad | None = None
        self._procs: dict[int, psutil.Process] = {}
        psutil.cpu_percent(None)  # the first reading is meaningless; start the interval now

    # -- lifecycle

    def on_start(self) -> None:
        self._feed = RevocationFeed(self.session, self.realm, self._registry_key, self.verifier)
        self.publisher = self.track(
            self.session.declare_publisher(keys.host_load(self.realm, self.ident))
        )
        self.serve(keys.host_spawn(self.realm, self.ident), self._on_spawn)
        # Not self.serve: a reply must carry this host's own key, or the answers of
        # several hosts to one `host/*/load` query are consolidated into one.
        self.track(
            self.session.declare_queryable(
                keys.host_load(self.realm, self.ident), self._on_load_query
            )
        )
        self._load_thread = threading.Thread(target=self._report, name="load", daemon=True)
        self._load_thread.start()

    def on_stop(self, timeout: float) -> None:
        if self._feed is not None:
            self._feed.close()
        if self._load_thread is not None:
            self._load_thread.join(timeout)

    def adopt(self, world: str, map_name: str, children: list[Child], robots: int) -> None:
        """Count a world of the lab file as one of this host's arenas (owner "lab")."""
        info = ArenaInfo(
            world=world,
            host=self.ident,
            map=map_name,
            robots=robots,
            owner="lab",
            state="running",
            started_at=time.time(),
        )
        with self._lock:
            self.arenas[world] = Arena(info, children)

    # -- load

    def load(self) -> HostLoad:
        mem = psutil.virtual_memory()
        cpu = psutil.cpu_percent(None)
        arenas = []
        with self._lock:
            current = list(self.arenas.values())
        for arena in current:
            rss = cpu_arena = 0.0
            pids = []
            state = arena.info.state
            for child in arena.children:
                proc = child.process
                if proc is None:
                    continue
                if proc.poll() is not None or child.restart_at is not None:
                    state = "restarting"
                    continue
                pids.append(proc.pid)
                try:
                    p = self._procs.get(proc.pid)
                    if p is None:  # keep the object: cpu_percent measures since its last call
                        p = self._procs[proc.pid] = psutil.Process(proc.pid)
                    rss += p.memory_info().rss / 2**20
                    cpu_arena += p.cpu_percent(None)
                except psutil.Error:
                    continue
            arenas.append(
                ArenaInfo(
                    world=arena.info.world,
                    host=self.ident,
                    map=arena.info.map,
                    robots=arena.info.robots,
                    owner=arena.info.owner,
                    state=state,
                    started_at=arena.info.started_at,
                    pids=pids,
                    rss_mb=round(rss, 1),
                    cpu_percent=round(cpu_arena, 1),
                )
            )
        reason = self._refusal(len(arenas), cpu, mem.available / 2**20)
        in_arenas = {id(c) for arena in current for c in arena.children}
        services = [
            c.spec.name + ("" if c.process is not None and c.process.poll() is None else " (down)")
            for c in list(self.supervisor.children)
            if id(c) not in in_arenas
        ]
        return HostLoad(
            host=self.ident,
            at=time.time(),
            cpus=psutil.cpu_count() or 1,
            cpu_percent=min(100.0, cpu),
            load1=os.getloadavg()[0],
            mem_total_mb=round(mem.total / 2**20, 1),
            mem_available_mb=round(mem.available / 2**20, 1),
            services=services,
            arenas=arenas,
            max_arenas=self.lab.limits.max_arenas_per_host if self.ctx.host.arenas else 0,
            accepting=not reason,
            reason=reason,
        )

    def _refusal(self, count: int, cpu: float, available_mb: float) -> str:
        limits = self.lab.limits
        if not self.ctx.host.arenas:
            return "this host takes no arenas (arenas = false in the lab file)"
        if count >= limits.max_arenas_per_host:
            return f"already runs {count} arenas (limits.max_arenas_per_host)"
        if cpu > limits.max_cpu_percent:
            return f"CPU at {cpu:.0f} % (over limits.max_cpu_percent {limits.max_cpu_percent:.0f})"
        if available_mb < limits.min_free_memory_mb:
            return f"only {available_mb:.0f} MB free (limits.min_free_memory_mb)"
        return ""

    def _report(self) -> None:
        period = self.lab.limits.load_period_s
        while not self._stopped.wait(period):
            try:
                self._latest = self.load()
                self.publisher.put(encode(self._latest))
            except Exception as exc:  # the session may be closing; the next round retries
                self.log.debug("load report: %s", exc)

    def _on_load_query(self, query: zenoh.Query) -> None:
        try:
            if query.payload is not None:
                decode(query.payload, LoadRequest)
            reply: HostLoad | ErrorReply = self.load()
        except MessageError as exc:
            reply = ErrorReply(code="bad_request", message=str(exc))
        except Exception as exc:
            self.log.exception("load report failed")
            reply = ErrorReply(code="internal", message=f"load report failed: {exc}")
        try:
            query.reply(keys.host_load(self.realm, self.ident), encode(reply))
        except Exception as exc:  # the querier may have gone away
            self.log.debug("could not reply with the load: %s", exc)

    # -- arenas

    def _on_spawn(self, query: zenoh.Query) -> ArenaReply | OkReply:
        key = str(query.key_expr)
        principal, request = self.verifier.open(key, query.payload, (SpawnArena, StopArena))
        if isinstance(request, StopArena):
            principal.require("host", "stop arenas")
            return self.stop_arena(request.world, by=principal.user)
        principal.require("host", "start arenas")
        return ArenaReply(arena=self.start_arena(request, owner=principal.user))

    def start_arena(self, request: SpawnArena, owner: str) -> ArenaInfo:
        limits = self.lab.limits
        if request.robots is not None and request.robots > limits.max_robots_per_arena:
            raise RequestError(
                "bad_request",
                f"{request.robots} robots is over the lab's limit of {limits.max_robots_per_arena}",
            )
        with self._spawn_lock:
            alive = keys.alive(self.realm, AliveKind.WORLD, request.world)
            with self._lock:
                taken = request.world in self.arenas
            if taken or (
                self.supervisor.watch is not None and self.supervisor.watch.present(alive)
            ):
                raise RequestError("conflict", f"a world named {request.world} already runs")
            reason = self.load().reason
            if reason:
                raise RequestError("unavailable", f"host {self.ident} takes no arena now: {reason}")
            try:
                map_path = resolve_map(self.lab, request.map)
            except (FileNotFoundError, ValueError) as exc:
                raise RequestError("not_found", str(exc)) from None
            robots = request.robots or 0
            if robots:
                map_path = map_with_robots(
                    map_path, robots, self.ctx.state_dir / "arenas" / f"{request.world}.json"
                )
            info = ArenaInfo(
                world=request.world,
                host=self.ident,
                map=request.map,
                robots=robots,
                owner=owner,
                state="starting",
                started_at=time.time(),
            )
            arena = Arena(info)
            with self._lock:
                self.arenas[request.world] = arena
            self.log.info("starting arena %s (%s) for %s", request.world, request.map, owner)
            for spec in arena_specs(
                self.ctx, request.world, map_path, seed=request.seed, robots=robots
            ):
                child = self.supervisor.add(spec)
                arena.children.append(child)
                self.supervisor.spawn(child)
                if not self.supervisor.wait_ready(child):
                    self._discard(request.world)
                    raise RequestError(
                        "internal", f"{spec.name} did not come up on {self.ident}; see its log"
                    )
            running = ArenaInfo(**{**_fields(info), "state": "running"})
            arena.info = running
            return running

    def stop_arena(self, world: str, by: str) -> OkReply:
        with self._lock:
            arena = self.arenas.get(world)
        if arena is None:
            raise RequestError("not_found", f"host {self.ident} runs no arena named {world}")
        if arena.info.owner == "lab":
            raise RequestError("forbidden", f"{world} is in the lab file; remove it there instead")
        self._discard(world)
        self.log.info("stopped arena %s for %s", world, by)
        return OkReply(detail=f"arena {world} stopped on {self.ident}")

    def _discard(self, world: str) -> None:
        with self._lock:
            arena = self.arenas.pop(world, None)
        if arena is not None:
            for child in reversed(arena.children):
                self.supervisor.stop_child(child)


def _fields(info: ArenaInfo) -> dict[str, object]:
    return {name: getattr(info, name) for name in info.__struct_fields__}


# --- the process -----------------------------------------------------------------------


def prepare(lab: LabFile, host_name: str, state_dir: Path | None) -> HostContext:
    """Validate that this host can run its share, and write its Zenoh configs."""
    host = lab.host(host_name)
    check_available(lab, host)
    state = state_dir or (lab.state_dir / host.name if lab.state_dir else None)
    if state is None:
        from services.up import default_state_dir

        state = default_state_dir(lab.realm) / host.name
    state.mkdir(parents=True, exist_ok=True)
    ctx = HostContext(lab=lab, host=host, state_dir=state, registry_key=read_registry_key(lab))
    write_configs(ctx)
    if "registry" in host.kinds():
        provision_registry_host(ctx)
    return ctx


def provision_registry_host(ctx: HostContext) -> None:
    """The registry's DB, its admin account, and every service account of the lab."""
    import json

    from services.certs import ACCOUNTS, registry_key_path
    from services.registry import provision
    from services.up import register_service_accounts

    identity, password, _ = provision(ctx.state_dir / "registry.db", registry_key_path(ctx.lab))
    if identity.verify_key.hex() != ctx.registry_key:
        raise LabFileError(
            f"{registry_key_path(ctx.lab)} does not match {ctx.lab.security.pki / 'registry.pub'}"
        )
    path = ctx.lab.security.pki / ACCOUNTS
    try:
        accounts = {
            name: bytes.fromhex(hexkey) for name, hexkey in json.loads(path.read_text()).items()
        }
    except (OSError, ValueError) as exc:
        raise LabFileError(f"cannot read the service accounts in {path}: {exc}") from None
    register_service_accounts(ctx.state_dir / "registry.db", accounts)
    if password is not None:
        print(
            f"  first start: user 'admin', password {password}\n"
            f"    (kept in {ctx.state_dir / 'admin-password.txt'})",
            flush=True,
        )


def run_host(ctx: HostContext, stop: threading.Event) -> int:
    """Run this host's share until ``stop`` is set, then stop it all in order."""
    supervisor = Supervisor(ctx.state_dir / "logs", say=lambda text: print(text, flush=True))
    host = ctx.host
    print(
        f"wart host {host.name} of lab '{ctx.realm}' ({ctx.lab.path}): state and logs in "
        f"{ctx.state_dir}",
        flush=True,
    )
    session: zenoh.Session | None = None
    service: HostService | None = None
    code = 0
    try:
        router = supervisor.add(router_spec(ctx))
        supervisor.spawn(router)
        options = NetworkOptions(
            realm=ctx.realm,
            mode="client",
            connect=(host.local_endpoint,),
            config_file=ctx.config_path("host"),
            registry_key=ctx.registry_key,
        )
        try:
            session = open_session(options, wait=30.0, quiet=True)
        except ConnectionError as exc:
            print(f"  ✗ {exc}", flush=True)
            return 1
        supervisor.watch = AliveWatch(session, keys.alive_all(ctx.realm))
        if not supervisor.wait_ready(router):
            return 1
        service = HostService(session, ctx, supervisor).start()
        engines = {s.ident: s for s in host.services if s.kind == "engine"}
        arena_children: dict[str, list[Child]] = {}
        for spec in host_plan(ctx):
            if stop.is_set():
                break
            child = supervisor.add(spec)
            supervisor.spawn(child)
            if not supervisor.wait_ready(child):
                code = 1
            # An engine of the lab file and its agent context are one arena (named
            # "engine W" and "agent W" by arena_specs), counted in the load reports.
            kind, _, world = spec.name.partition(" ")
            if kind in ("engine", "agent") and world in engines:
                arena_children.setdefault(world, []).append(child)
        for world, children in arena_children.items():
            svc = engines[world]
            service.adopt(world, str(svc.params["map"]), children, int(svc.params.get("robots", 0)))
        if not stop.is_set():
            print(f"Host {host.name} is running. Press Ctrl-C to stop it.", flush=True)
            supervisor.run_until(stop)
    finally:
        print(f"Stopping host {host.name}...", flush=True)
        if service is not None:
            service.stop()
        supervisor.stop_all()
        if session is not None:
            close_session(session)
        print(f"Host {host.name} stopped.", flush=True)
    return code


def main(argv: Sequence[str] | None = None, prog: str = "wart host") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("--lab", type=Path, required=True, help="the lab file (deploy/lab.example.toml)")
    p.add_argument("--name", required=True, help="which host of the lab file this machine is")
    p.add_argument("--state-dir", type=Path, help="database, logs, generated configs")
    p.add_argument(
        "--check",
        action="store_true",
        help="validate, write this host's Zenoh configs, print what would run, and exit",
    )
    args, _ = cli.parse(p, argv)
    try:
        ctx = prepare(load(args.lab), args.name, args.state_dir)
        if args.check:
            for spec in [router_spec(ctx), *host_plan(ctx)]:
                print(f"{spec.name:<16} wart {' '.join(spec.argv)}")
            print(f"configs in {ctx.state_dir / 'zenoh'}")
            return 0
    except (LabFileError, FileNotFoundError, OSError, ValueError) as exc:
        return cli.fail(str(exc))
    stop = threading.Event()

    def on_signal(_signum: int, _frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return run_host(ctx, stop)


if __name__ == "__main__":
    sys.exit(main())
