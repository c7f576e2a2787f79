"""Every tick of the engine bench's world, hashed: two runs (threads, checkouts) compared.

Builds ``bench/engine_bench.py``'s world (N Khepera, the discs drive, the full
scenario with ``--balls 0.5``), runs ``--ticks`` ticks of the avoidance rule and
a step, and after each hashes everything a tick moves or reads: poses,
velocities, counters, the objects' poses, the proximity, ambient and presence
readings. Prints one line per tick (tick, that tick's hash) and the chain of
them last, so two runs are compared with ``diff`` or by their last line:

    .venv/bin/python -m bench.drive_hashes --robots 10000 --balls 0.5 --threads 1 > one.txt
    .venv/bin/python -m bench.drive_hashes --robots 10000 --balls 0.5 --threads 2 > two.txt
    diff one.txt two.txt

``--split-from 1`` splits the drive of a small world too (it starts at
discs_split.SPLIT_MIN_DISCS discs).

Another checkout's run: from its directory, ``PYTHONPATH=. python -m
bench.drive_hashes ...`` with this file copied into its bench/ (issue 35: the
drive split over threads against the serial drive before it).
"""

from __future__ import annotations

import hashlib

from bench import cli as bench_cli
from common.sim2d import discs_split, sensing
from tests.kit.worlds import build, control, tick_digest


def main(argv: list[str] | None = None) -> None:
    p = bench_cli.parser("drive_hashes", __doc__)
    p.add_argument("--robots", type=int, default=1000)
    p.add_argument("--balls", type=float, default=0.5, help="movable balls per robot")
    p.add_argument("--threads", type=int, default=1, help="World.threads")
    p.add_argument("--ticks", type=int, default=100)
    p.add_argument("--profile", action="store_true", help="the general path (World.profile)")
    p.add_argument(
        "--split-from",
        type=int,
        metavar="DISCS",
        help="split the drive over the threads from this many discs, sense on them from 1 "
        "robot (discs_split.SPLIT_MIN_DISCS, sensing.PARALLEL_MIN_AGENTS: small worlds' paths)",
    )
    args = p.parse_args(argv)
    if args.robots <= 0 or args.ticks <= 0 or args.threads <= 0:
        p.error("--robots, --ticks and --threads must be positive")
    if not 0 <= args.balls <= 10:
        p.error("--balls must be between 0 and 10")
    if args.split_from is not None:
        discs_split.SPLIT_MIN_DISCS = args.split_from
        sensing.PARALLEL_MIN_AGENTS = 1
    world = build(args.robots, threads=args.threads, drive="discs", balls=args.balls)
    world.profile = args.profile
    chain = hashlib.sha256()
    for t in range(args.ticks):
        control(world)
        world.step()
        digest = tick_digest(world)
        chain.update(digest.encode())
        print(t + 1, digest[:16], flush=True)
    print("chain", chain.hexdigest())


if __name__ == "__main__":
    main()
