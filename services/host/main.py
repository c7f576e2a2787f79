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

import sys
import threading
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli, keys
from common.keys import AliveKind
from common.service import stop_on_signals
from common.zconfig import NetworkOptions
from services.lab import provision
from services.lab.driver import HostDriver
from services.lab.hosting import HostingPlan, HostingService
from services.lab.labfile import LabFile, LabFileError, load
from services.lab.pki import ACCOUNTS, registry_key_path
from services.lab.plan import (
    HostContext,
    check_available,
    host_plan,
    host_state_dir,
    host_waves,
    read_registry_key,
    router_spec,
    write_configs,
)
from services.lab.supervisor import Child, ChildSpec, Supervisor
from services.lab.wiring import arena_context


class HostService(HostingService):
    """The hosting service of a lab file's host (see services/lab/hosting.py)."""

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
    state = host_state_dir(lab, host, state_dir)
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


class LabFileHost(HostDriver):
    """A lab file's host under the shared driver (services/lab/driver.py)."""

    hosting_first = True  # its load and token are there while its services start

    def __init__(self, ctx: HostContext) -> None:
        super().__init__(ctx.realm, ctx.state_dir)
        self.ctx = ctx
        self.host_log = f"host-{ctx.host.name}.log"

    def banner(self) -> str:
        ctx = self.ctx
        return (
            f"wart host {ctx.host.name} of lab '{ctx.realm}' ({ctx.lab.path}): state and logs "
            f"in {ctx.state_dir}"
        )

    def router(self) -> ChildSpec:
        return router_spec(self.ctx)

    def network(self) -> NetworkOptions:
        return self.ctx.network("host")

    def waves(self) -> list[list[ChildSpec]]:
        return host_waves(self.ctx)

    def hosting(self, session: zenoh.Session, supervisor: Supervisor) -> HostingService:
        return HostService(session, self.ctx, supervisor).start()

    def adopt(self, hosting: HostingService, children: list[Child]) -> None:
        realm = self.realm
        engines = {s.ident: s for s in self.ctx.host.services if s.kind == "engine"}
        # An engine of the lab file and its agent context are one arena: told
        # apart by their tokens (the world's, and its context's).
        arena_of = {keys.alive(realm, AliveKind.WORLD, w): w for w in engines} | {
            keys.alive(realm, AliveKind.CONTEXT, arena_context(w, s.params.get("context"))): w
            for w, s in engines.items()
        }
        arena_children: dict[str, list[Child]] = {}
        for child in children:
            world = arena_of.get(child.spec.alive_key or "")
            if world is not None:  # counted in the load reports
                arena_children.setdefault(world, []).append(child)
        for world, mine in arena_children.items():
            svc = engines[world]
            hosting.adopt(world, str(svc.params["map"]), mine, int(svc.params.get("robots", 0)))

    def running(self) -> str:
        return f"Host {self.ctx.host.name} is running. Press Ctrl-C to stop it."

    def stopping(self) -> str:
        return f"Stopping host {self.ctx.host.name}..."

    def stopped(self) -> str:
        return f"Host {self.ctx.host.name} stopped."


def run_host(ctx: HostContext, stop: threading.Event) -> int:
    """Run this host's share until ``stop`` is set, then stop it all in order."""
    return LabFileHost(ctx).run(stop)


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
                print(f"{spec.name:<22} wart {' '.join(spec.argv)}")
            print(f"configs in {ctx.state_dir / 'zenoh'}")
            return 0
    except (LabFileError, FileNotFoundError, OSError, ValueError) as exc:
        return cli.fail(str(exc))
    return run_host(ctx, stop_on_signals())


if __name__ == "__main__":
    sys.exit(main())
