"""``wart engine``: one simulated world (the Sim2D engine) on the lab's Zenoh network.

    wart engine --map maps/foraging.json --world arena1 --seed 7 [--speed X | --fast]

Loads the map (errors name the field and line), steps the world every
--tick-ms of simulated time, paced to the wall clock (times --speed, or as
fast as it goes with --fast), publishes frames and sensor samples, obeys
commands from lease holders, and serves snapshots, live edits and map
save/load (maps are saved only in --maps-dir).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli
from common.client.service_login import add_world_args, world_login
from common.keys import is_ident
from common.robots import registry as robot_registry
from common.service import run_service
from common.sim2d import compiled
from common.sim2d.drives import DEFAULT_DRIVE, DRIVES
from common.sim2d.maps import MapError, load_map
from common.sim2d.packs import MAX_THREADS
from common.sim2d.world import World
from services.engine.service import STREAMS_UP_FRONT, EngineService, EngineSettings


def main(argv: Sequence[str] | None = None, prog: str = "wart engine") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("--map", type=Path, required=True, help="the map file to load (JSON)")
    p.add_argument("--world", help="this world's name (default: the map file's name)")
    p.add_argument("--seed", type=int, default=0, help="noise seed: same seed, same run")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, default=1.0, help="times real time (default 1)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible (headless runs)")
    p.add_argument("--tick-ms", type=float, default=20.0, help="simulated ms a tick (default 20)")
    p.add_argument(
        "--wander",
        action="store_true",
        help="robots no controller drives avoid obstacles on their own (demos, swarm displays)",
    )
    p.add_argument(
        "--maps-dir",
        type=Path,
        help="where map save/load requests read and write (default: the map's directory)",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="threads of the sensing pass, used from 256 robots up (default 1; up to "
        f"{MAX_THREADS}, this machine's cores); readings are the same with any count. "
        "Measured on 2 cores: no gain at 1,000 robots, slower when the other core is busy",
    )
    p.add_argument(
        "--physics-threads",
        type=int,
        default=1,
        help="threads of chipmunk's solver (default 1; more: its threaded space, whose "
        "trajectories depend on scheduling)",
    )
    p.add_argument(
        "--drive",
        choices=DRIVES,
        default=DEFAULT_DRIVE,
        help="how robots are driven: discs (default; robots and movable objects as discs "
        "moved by their wheels and pushes, contacts solved by one compiled solver), "
        "joints (pymunk's tank pattern: chipmunk's constraints) or velocity (a "
        "force-limited servo without joints, tongs that hit movable objects only): "
        "docs/WORLDS.md, 'Drives'",
    )
    p.add_argument(
        "--streams-up-front",
        type=int,
        default=STREAMS_UP_FRONT,
        metavar="N",
        help=f"declare every robot's sensor publisher at start in worlds of up to N robots "
        f"(default {STREAMS_UP_FRONT}); in bigger ones, a robot's publisher is declared when "
        "someone watches it (a liveliness token on its agent/<a>/watch key, which the lab's "
        "viewer and robot clients declare) or it is leased. Zenoh's cost per publisher "
        "grows with their number: 10,000 took 35 s here",
    )
    p.add_argument(
        "--robots-dir",
        type=Path,
        metavar="DIR",
        help="robot files (*.toml) of this lab, beside the shipped types and the installed "
        "plugins' (default: WART_ROBOTS_DIR), and where robot types users save go; a "
        "refused file is logged and left out (docs/ROBOTS.md)",
    )
    add_world_args(p)
    args, options = cli.parse_networked(p, argv)
    if args.user and (args.identity is None or not options.registry_key):
        p.error("--user needs --identity and --registry-key")
    world_name = args.world or args.map.stem
    if not is_ident(world_name):
        p.error(f"--world {world_name!r} is not a valid name (letters, digits, _ - .)")
    if not 0.1 <= args.tick_ms <= 1000:
        p.error("--tick-ms must be between 0.1 and 1000")
    if not 0.01 <= args.speed <= 10_000:
        p.error("--speed must be between 0.01 and 10000")
    if args.watchdog_ms <= 0:
        p.error("--watchdog-ms must be positive")
    if args.streams_up_front < 0:
        p.error("--streams-up-front must be 0 or more")
    for flag, value in (("--threads", args.threads), ("--physics-threads", args.physics_threads)):
        if not 1 <= value <= MAX_THREADS:
            p.error(f"{flag} must be between 1 and {MAX_THREADS} (numba's thread pool)")
    registry_key = cli.registry_key(p, options)
    tick_s = args.tick_ms / 1000.0
    if args.robots_dir is not None:
        try:
            args.robots_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            p.error(f"--robots-dir {args.robots_dir}: {exc.strerror or exc}")
        robot_registry.use(robots_dir=args.robots_dir)

    def load() -> World:
        return load_map(
            args.map,
            name=world_name,
            seed=args.seed,
            tick_s=tick_s,
            threads=args.threads,
            physics_threads=args.physics_threads,
            drive=args.drive,
        )

    try:
        world = load()
    except MapError as exc:
        return cli.fail(str(exc))
    # Load the per-tick kernels now rather than on the first tick: the ahead-of-time
    # module (common/sim2d/aot.py) if it is built for these sources, else numba's
    # (compiled, or loaded from its on-disk cache). Said first: without the module, a
    # checkout's first start compiles for a while.
    print(f"engine: kernels: {compiled.WHY}", file=sys.stderr, flush=True)
    if compiled.PATH == "jit":
        print(
            "engine: loading numba's kernels (a checkout's first start compiles them: "
            "a minute or more on 2 cores; cached after)",
            file=sys.stderr,
            flush=True,
        )
    print(f"engine: kernels ready in {compiled.warm_up():.2f} s", file=sys.stderr, flush=True)
    # A few ticks of a throwaway copy of this world before its token is declared: a drive
    # or an object with no ahead-of-time kernel loads numba's at its first tick, and
    # under load that first tick took seconds in a world that said it was up.
    t0 = time.perf_counter()
    rehearsal = load()
    for _ in range(3):
        rehearsal.step()
    del rehearsal
    print(f"engine: first ticks in {time.perf_counter() - t0:.2f} s", file=sys.stderr, flush=True)
    settings = EngineSettings(
        tick_s=tick_s,
        speed=args.speed,
        fast=args.fast,
        watchdog_s=args.watchdog_ms / 1000.0,
        maps_dir=args.maps_dir or args.map.parent,
        base_map=args.map.stem,
        seed=args.seed,
        registry_key=registry_key,
        wander=args.wander,
        threads=args.threads,
        physics_threads=args.physics_threads,
        drive=args.drive,
        streams_up_front=args.streams_up_front,
    )

    def build(session: zenoh.Session) -> EngineService:
        login = world_login(session, options.realm, registry_key, args.user, args.identity)
        identity = (lambda: login.session) if login is not None else None
        return EngineService(session, options.realm, world, settings, identity=identity)

    return run_service(f"engine {world_name}", options, build)


if __name__ == "__main__":
    sys.exit(main())
