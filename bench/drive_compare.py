"""What changes for a user between two drives: the four examples, a seeded minute each.

For each example of examples/ in the map it suits, every Khepera of the map
runs its own instance of the controller (as an arena where every robot was
given the example would) for ``--seconds`` of simulated time, once per drive,
same seed. Printed per example and drive:

- distance: the path all robots drove, summed (mm);
- contacts: how many times a robot came to touch something (a wall, an
  obstacle, another robot, an object) as its drive sees it, the runner's dry
  run's measure (services/runner/dryrun.py): chipmunk's contacts of the
  robot's body, tongs included, on the joints drive; its disc within 0.5 mm
  on the discs drive;
- pushed: objects moved more than 5 mm from where they started, and the
  distance all objects moved (mm); for 04, balls in the nest at the end;
- IR at a wall: the mean of a robot's highest IR reading over the ticks it
  touched a wall or an obstacle (so touching, on the joints drive, may be a
  lowered tong's touch, 25 mm ahead of the body).

Then a probe of one robot driven straight at a wall (arm down, then arm up):
where it stops and what its two front sensors read there. Run:

    .venv/bin/python -m bench.drive_compare [--seconds 60] [--seed 1]
        [--drives joints discs]

Figures: docs/BENCHMARKS.md, "The discs drive for every world (issue 35)".
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench import cli as bench_cli
from common.controller import Controller, Khepera, load_controller
from common.sim2d import kernels
from common.sim2d.agents import agent_type
from common.sim2d.drives import DRIVES
from common.sim2d.maps import load_map
from common.sim2d.world import World
from services.runner.lockstep import Touches
from tests.kit.worldlink import WorldLink

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = {  # example -> the map it suits (its docstring's "Suits:")
    "01_braitenberg": "maze",
    "02_wall_following": "maze",
    "03_phototaxis": "phototaxis",
    "04_foraging": "foraging",
}
NEST = (250.0, 600.0, 150.0)  # maps/foraging.json's nest: x, y, radius


@dataclass
class Result:
    distance: float
    contacts: dict[str, int]
    pushed: int
    object_travel: float
    in_nest: int
    ir_at_wall: float


def run_example(name: str, drive: str, seconds: float, seed: int) -> Result:
    world = load_map(REPO / "maps" / f"{EXAMPLES[name]}.json", name="t", seed=seed, drive=drive)
    path = REPO / "examples" / f"{name}.py"
    robots: list[tuple[Controller, Khepera, int]] = []
    for agent in world.agents:
        if agent.spec.name != "khepera":
            continue
        controller = load_controller(path)
        robot = Khepera(WorldLink(world, agent.id))
        robots.append((controller, robot, world.agent_slot(agent.id)))
    # Through pose_of: a world's object_pose is filled by its first tick.
    start_objects = np.array([world.pose_of(o.id) for o in world.objects]).reshape(-1, 3)
    last = world.agent_pose[:, :2].copy()
    touches = {slot: Touches(world, slot) for _c, _r, slot in robots}
    contacts = {"wall": 0, "obstacle": 0, "robot": 0, "object": 0}
    distance = 0.0
    ir_sum, ir_ticks = 0.0, 0
    period = robots[0][0].period
    ticks = max(1, round(period / world.tick_s))
    quiet = io.StringIO()  # the examples print their state changes
    with contextlib.redirect_stdout(quiet):
        for controller, robot, _ in robots:
            controller.initialize(robot)
        t = 0.0
        while t < seconds:
            for controller, robot, _ in robots:
                controller.do_work(robot)
            for _ in range(ticks):
                world.step()
                pose = world.agent_pose
                distance += float(np.hypot(*(pose[:, :2] - last).T).sum())
                last = pose[:, :2].copy()
                for _c, _r, slot in robots:
                    for what, _ident in touches[slot].new_contacts():
                        contacts[what] += 1
                    if any(w in ("wall", "obstacle") for w, _ in touches[slot].touching):
                        ir_sum += float(world.proximity[slot].max())
                        ir_ticks += 1
            t += ticks * world.tick_s
    moved = np.hypot(*(world.object_pose[:, :2] - start_objects[:, :2]).T)
    in_nest = sum(
        math.dist(world.object_pose[j, :2], NEST[:2]) < NEST[2] for j in range(len(world.objects))
    )
    return Result(
        distance,
        contacts,
        int((moved > 5.0).sum()),
        float(moved.sum()),
        int(in_nest) if name.startswith("04") else 0,
        ir_sum / ir_ticks if ir_ticks else float("nan"),
    )


def wall_probe(drive: str, arm: int) -> tuple[float, float]:
    """A lone Khepera driven at 20 into the east wall for 3 s: its gap to the wall, front IR."""
    world = World(1000.0, 600.0, seed=1, tick_s=0.01, drive=drive)
    world.add_agent("k", agent_type("khepera"), 700.0, 300.0, 0.0)
    world.set_arm(0, arm)
    world.set_speeds(0, 20, 20)
    world.run(3.0)
    gap = world.width - world.agent_pose[0, 0] - world.tables.radius[0]
    return float(gap), float(world.proximity[0, 2:4].mean())


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("drive_compare", __doc__)
    p.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per example")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--drives", nargs=2, choices=DRIVES, default=["joints", "discs"])
    args = p.parse_args(argv)
    if not 0 < args.seconds <= 3600:
        p.error("--seconds must be above 0 and at most 3600")
    print(f"kernels ready in {kernels.warm_up():.2f} s")
    print(
        f"seed {args.seed}, {args.seconds:g} simulated s each; load average "
        + " ".join(f"{x:.2f}" for x in os.getloadavg())
    )
    print(
        f"{'example':<18} {'drive':<7} {'distance mm':>11} {'contacts w/o/r/obj':>19} "
        f"{'pushed':>6} {'obj mm':>7} {'nest':>4} {'IR at wall':>10}"
    )
    for name in EXAMPLES:
        for drive in args.drives:
            r = run_example(name, drive, args.seconds, args.seed)
            c = r.contacts
            touches = f"{c['wall']}/{c['obstacle']}/{c['robot']}/{c['object']}"
            print(
                f"{name:<18} {drive:<7} {r.distance:>11.0f} {touches:>19} {r.pushed:>6} "
                f"{r.object_travel:>7.0f} {r.in_nest:>4} {r.ir_at_wall:>10.0f}",
                flush=True,
            )
    print("a Khepera driven into a wall at speed 20 for 3 s: gap to the wall (mm), front IR")
    for drive in args.drives:
        for arm, label in ((255, "arm down"), (165, "arm up")):
            gap, ir = wall_probe(drive, arm)
            print(f"  {drive:<7} {label:<9} gap {gap:5.1f} mm, IR {ir:5.0f}")
    print("load average after: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
