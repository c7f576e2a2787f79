"""Emergency stop: time from the host's request to the last of four driven robots at rest.

Real processes on 127.0.0.1 (router, registry, a Sim2D engine with a service
identity, so leases are MAC leases as under ``wart up``; the runner; the
agent context ``arena``), as in tests/integration/test_emergency_stop.py.
Each round: three students deploy a controller that drives forward on k0..k3
(at 12 units, about 96 mm/s), the robots are seen moving, the host (ida)
sends the emergency stop; then, from this process:

- reply: the host's request until its OkReply;
- ended: until the last of the four students got "cancelled: emergency stop by ida";
- at rest: until the first frame from which every robot moves under 0.05 mm
  a frame for 10 frames (frame arrival times here, so it includes the frame's
  own delivery, a few ms).

Then the host releases the stop and the next round starts.

    .venv/bin/python -m bench.bench_estop --rounds 7
"""

from __future__ import annotations

import functools
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench import cli as bench_cli
from common.client.agent_client import FINAL
from tests.kit.agentkit import (
    Motion,
    agent_users,
    deploy_running,
    start_agent_lab,
)
from tests.kit.lab import make_lab
from tests.kit.procs import Procs, start_router
from tests.kit.waits import wait_for

REPO = Path(__file__).resolve().parent.parent

FORWARD = (REPO / "tests" / "integration" / "controllers" / "forward.py").read_bytes()
ROBOTS = ("k0", "k1", "k2", "k3")


def main() -> int:
    p = bench_cli.parser("bench_estop", __doc__)
    p.add_argument("--rounds", type=int, default=7)
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="wart-bench-estop-"))
    procs = Procs(tmp)
    replies: list[float] = []
    ended: list[float] = []
    rests: list[float] = []
    try:
        router = start_router(procs, f"bench{int(time.time()) % 100000}")
        lab = make_lab(router, procs, tmp)
        start_agent_lab(lab, identity=True, slot=300.0)
        with (
            lab.zsession() as z,
            agent_users(lab, "alice", "bob", "carol", "ida") as (alice, bob, carol, ida),
        ):
            motion = Motion(z, router.realm)
            owners = {"k0": alice, "k1": bob, "k2": carol, "k3": alice}
            for n in range(args.rounds):
                rids = deploy_running(owners, FORWARD, filename="controller.py")
                since = time.monotonic()
                wait_for(functools.partial(motion.moving, ROBOTS, since), 30, "robots moving")
                t0 = time.monotonic()
                ida.emergency_stop("bench")
                replies.append(time.monotonic() - t0)
                last = 0.0
                for agent, who in owners.items():
                    status = who.wait_status(rids[agent], FINAL, timeout=20)
                    assert status is not None and "emergency stop by ida" in status.reason
                    last = max(last, time.monotonic() - t0)
                ended.append(last)
                rest = wait_for(functools.partial(motion.at_rest_since, ROBOTS, t0), 20, "rest")
                assert isinstance(rest, float)
                rests.append(rest - t0)
                print(
                    f"round {n + 1}: reply {replies[-1] * 1000:.0f} ms, all told "
                    f"{ended[-1] * 1000:.0f} ms, last robot at rest {rests[-1] * 1000:.0f} ms",
                    flush=True,
                )
                ida.emergency_stop(release=True)
            motion.close()
    finally:
        procs.stop_all()

    def ms(values: list[float]) -> str:
        return (
            f"median {statistics.median(values) * 1000:.0f} ms "
            f"(min {min(values) * 1000:.0f}, max {max(values) * 1000:.0f})"
        )

    print(f"\n{args.rounds} rounds, 4 deployed controllers each")
    print(f"reply to the host:        {ms(replies)}")
    print(f"every student told:       {ms(ended)}")
    print(f"last robot at rest:       {ms(rests)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
