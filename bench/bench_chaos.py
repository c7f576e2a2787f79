"""Chaos: kill -9 each service of a running ``wart up`` lab, with clients attached.

For every service it prints how long until the service is back (every
liveliness token present before the kill is present again) and how long until
the clients are whole again without any user action: a terminal chat client's
new line reaches a second terminal client through the room. At the end a
fresh client reads the room's history: every line acknowledged before a kill
(seen by the other client) must still be there.

    python -m bench.bench_chaos                  # every service once
    python -m bench.bench_chaos --only registry --only router

The assertions on the same run live in tests/smoke/test_chaos.py; this prints
the figures that docs/BENCHMARKS.md records.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from bench import cli as bench_cli
from tests.kit.chaos import SERVICES, Chaos, DeployProbe, running_lab


def _fmt(value: float | None) -> str:
    return "never" if value is None else f"{value:5.2f} s"


def main(argv: Sequence[str] | None = None) -> int:
    p = bench_cli.parser("bench_chaos", __doc__)
    p.add_argument(
        "--only", action="append", choices=SERVICES, help="kill only this service (repeatable)"
    )
    p.add_argument("--deadline", type=float, default=30.0, help="give up on a service after (s)")
    args = p.parse_args(argv)
    services = args.only or list(SERVICES)
    print(f"chaos: starting a lab ({len(services)} services to kill)...", flush=True)
    with running_lab() as lab:
        chaos = Chaos(lab, args.deadline)
        deploy = DeployProbe(lab, lab.admin_password())
        if deploy.output.wait("running on k0", 60) is None:
            print("the deployed controller did not start:\n" + "\n".join(deploy.output.lines))
        try:
            print(f"{'service':<22} {'back':>8} {'clients whole':>14}", flush=True)
            for service in services:
                out = chaos.kill(service)
                note = f"  ({out.note})" if out.note else ""
                print(
                    f"{service:<22} {_fmt(out.back_s):>8} {_fmt(out.whole_s):>14}{note}", flush=True
                )
            lost = chaos.lost_lines()
            print(
                f"acknowledged chat lines: {len(chaos.acknowledged)}, lost: {len(lost)}"
                + (f" ({', '.join(lost)})" if lost else ""),
                flush=True,
            )
            print(f"the deployed controller (wart deploy): {deploy.ending(90)}", flush=True)
        finally:
            deploy.close()
            chaos.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
