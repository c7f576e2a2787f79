"""``wart runner``: the command line; what the service does is service.py's docstring."""

from __future__ import annotations

import sys
from collections.abc import Sequence

import zenoh

from common import cli
from common.client.service_login import ServiceCredentials
from common.service import run_service
from services.runner import service
from services.runner.sandbox import SandboxLimits, sandbox_problem
from services.runner.service import RunnerService


def main(argv: Sequence[str] | None = None, prog: str = "wart runner") -> int:
    p = cli.parser(prog, service.__doc__ or "")
    cli.add_account_arguments(
        p, "runner", "the runner's id (default runner)", "the runner's service account (with 'run')"
    )
    p.add_argument("--cpu-seconds", type=int, default=120, help="CPU time per controller")
    p.add_argument(
        "--memory-mb",
        type=int,
        default=256,
        help="memory per controller: a quarter is its writable space, the rest address space",
    )
    p.add_argument(
        "--cpu-share",
        type=float,
        default=0.5,
        help="cores per controller, where a cpu cgroup can be made (else nice 19 only)",
    )
    p.add_argument(
        "--hang-seconds",
        type=float,
        default=0.0,
        help="end a run whose do_work has not returned for this long, saying where it was "
        "(default 0: only near the slot's end)",
    )
    args, options = cli.parse_networked(p, argv)
    try:
        credentials = ServiceCredentials.of_service("runner", args, options)
    except ValueError as exc:
        return cli.fail(str(exc))
    if not (1 <= args.cpu_seconds <= 3600 and 64 <= args.memory_mb <= 8192):
        return cli.fail("--cpu-seconds must be 1..3600 and --memory-mb 64..8192")
    if not 0.05 <= args.cpu_share <= 64:
        return cli.fail("--cpu-share must be 0.05..64 cores")
    if not 0 <= args.hang_seconds <= 3600:
        return cli.fail("--hang-seconds must be 0 (off) .. 3600 seconds")
    problem = sandbox_problem()
    if problem:
        return cli.fail(f"cannot run uploaded controllers here: {problem}")
    limits = SandboxLimits(
        cpu_seconds=args.cpu_seconds,
        memory_bytes=args.memory_mb << 20,
        cpu_share=args.cpu_share,
        hang_seconds=args.hang_seconds,
    )

    def build(session: zenoh.Session) -> RunnerService:
        login = credentials.login(session, options.realm, f"runner {args.name}")
        return RunnerService(
            session,
            options.realm,
            args.name,
            registry_key=credentials.registry_key,
            login=login,
            limits=limits,
        )

    return run_service(f"runner {args.name}", options, build)


if __name__ == "__main__":
    sys.exit(main())
