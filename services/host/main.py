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

import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli, keys
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.commands.certs import ACCOUNTS, registry_key_path
from services.host.service import HostingPlan, HostingService
from services.lab import provision
from services.lab.labfile import LabFile, LabFileError, load
from services.lab.plan import (
    HostContext,
    check_available,
    host_plan,
    host_waves,
    read_registry_key,
    router_spec,
    write_configs,
)
from services.lab.supervisor import AliveWatch, Child, Supervisor
from services.lab.wiring import default_state_dir


class HostService(HostingService):
    """The hosting service of a lab file's host (see services/host/service.py)."""

    def __init__(self, session: zenoh.Session, ctx: HostContext, supervisor: Supervisor) -> None:
        plan = HostingPlan(
            wiring=ctx.wiring(),
            registry_key=ctx.registry_key,
            limits=ctx.lab.limits,
            # Chat rooms need a service account from the lab's PKI, which `wart certs`
            # makes only for the rooms the lab file names: none on request here.
            max_rooms=0,
            no_arenas_reason=""
            if ctx.host.arenas
            else "this host takes no arenas (arenas = false in the lab file)",
        )
        super().__init__(session, plan, supervisor)
        self.ctx = ctx


# --- the process -----------------------------------------------------------------------


def prepare(lab: LabFile, host_name: str, state_dir: Path | None) -> HostContext:
    """Validate that this host can run its share, and write its Zenoh configs."""
    host = lab.host(host_name)
    check_available(lab, host)
    state = state_dir or (lab.state_dir / host.name if lab.state_dir else None)
    if state is None:
        state = default_state_dir(lab.realm) / host.name
    state.mkdir(parents=True, exist_ok=True)
    ctx = HostContext(lab=lab, host=host, state_dir=state, registry_key=read_registry_key(lab))
    write_configs(ctx)
    if "registry" in host.kinds():
        provision_registry_host(ctx)
    return ctx


def provision_registry_host(ctx: HostContext) -> None:
    """The registry's DB, its admin account, and every service account of the lab."""
    done = provision.provision_registry_host(
        ctx.state_dir,
        registry_key_path(ctx.lab),
        ctx.lab.security.pki / ACCOUNTS,
        ctx.registry_key,
    )
    if done.admin_password is not None:
        print(
            f"  first start: user 'admin', password {done.admin_password}\n"
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
        # An engine of the lab file and its agent context are one arena (named
        # "engine W" and "agent C" by arena_specs, C the context's name).
        arena_of = {f"engine {w}": w for w in engines} | {
            f"agent {s.params.get('context') or w}": w for w, s in engines.items()
        }
        arena_children: dict[str, list[Child]] = {}
        for wave in host_waves(ctx):
            if stop.is_set():
                break
            for child, up in supervisor.start_together(wave):
                if not up:
                    code = 1
                if child.spec.name in arena_of:  # counted in the load reports
                    arena_children.setdefault(arena_of[child.spec.name], []).append(child)
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
