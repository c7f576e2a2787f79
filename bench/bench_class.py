"""A class of students at work on one lab: click to answer for Check, Dry run, Run and Stop.

A real lab as ``wart`` processes (router, registry, engine, runner, the arena's agent
context, the web viewer), each student a headless session speaking viser's protocol
to the viewer (tests/kit/viser_client.py: what a browser sends and receives, without
drawing). Each logs in, joins the arena, writes a controller and then works at a
class's pace: one action every 10 to 20 s (random), in the order a student works,
Check, Dry run, Run in simulation, Stop, again and again, each on their own robot.

Measured, from the student's side: the time from the click to the answer on the page
(the editor's status line changing to the result; a dry run's "a few simulated
seconds..." is not its answer); p50 and p95 by action; and runs lost: a run of a
student's that ended (cancelled or refused) before they pressed Stop.

    python -m bench.bench_class --students 30 --seconds 240
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import time
from dataclasses import dataclass, field
from pathlib import Path

from bench import cli as bench_cli
from bench.labproc import BenchLab
from bench.quantiles import percentile
from common.keys import AliveKind
from services.lab import wiring
from tests.kit.procs import free_port
from tests.kit.viser_client import GuiElement, ViserClient

ARENA, WORLD = "arena", "w1"
PASSWORD = "class-of-2026"
ACTIONS = ("Check", "Dry run", "Run in simulation", "Stop")
INTERIM = "a few simulated seconds"  # the dry run's own "working on it", not its answer
# What each action's answer says (Run and Dry run first say Check's verdict: not theirs).
ANSWERS = {
    "Check": lambda said: "Check" in said,
    "Dry run": lambda said: "Dry run of" in said and INTERIM not in said,
    "Run in simulation": lambda said: any(
        words in said for words in ("queued on", "runs on", "Not queued")
    ),
    "Stop": lambda said: any(
        words in said for words in ("Stopped", "cancelled", "Nothing of yours", "Not done")
    ),
}
CONTROLLER = """\
from common.controller import Controller, Khepera


class Gentle(Controller):
    period = 0.1

    def do_work(self, robot: Khepera) -> None:
        near = robot.proximity().values  # 0..5 round the front, left to right
        robot.set_speeds(3 - (near[3] > 500), 3 - (near[2] > 500))
"""


def class_map(path: Path, robots: int) -> None:
    """An empty arena with one robot per student on a grid, well apart."""
    side = 6
    rows = (robots + side - 1) // side
    agents = [
        {"id": f"k{i}", "type": "khepera", "x": 300 + 400 * (i % side),
         "y": 300 + 400 * (i // side), "heading_deg": 90}
        for i in range(robots)
    ]  # fmt: skip
    spec = {
        "format": "wart-map",
        "version": 1,
        "name": "class",
        "description": f"{robots} Khepera, one per student",
        "arena": {"width": 400 * side + 200, "height": 400 * rows + 200},
        "agents": agents,
    }
    path.write_text(json.dumps(spec))


@dataclass
class Student:
    index: int
    client: ViserClient
    robot: str
    latencies: dict[str, list[float]] = field(default_factory=lambda: {a: [] for a in ACTIONS})
    lost: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    runs: int = 0
    dropped: bool = False
    status: GuiElement | None = None

    @property
    def user(self) -> str:
        return f"s{self.index:02d}"

    def said(self) -> str:
        return str(self.status.props.get("_markdown", "")) if self.status else ""


def find_status(client: ViserClient) -> GuiElement | None:
    """The editor's status line: the first markdown after its Reset button."""
    after_reset = False
    for element in list(client.gui.values()):
        if element.kind == "GuiButtonMessage" and element.label == "Reset":
            after_reset = True
        elif after_reset and element.kind == "GuiMarkdownMessage":
            return element
    return None


async def enter(student: Student, gate: asyncio.Semaphore) -> None:
    c = student.client
    async with gate:  # a class logging in within a minute, a few at a time
        await c.connect()
        await c.log_in(student.user, PASSWORD, timeout=300)
        await c.join(ARENA, timeout=300)
    student.status = await c.wait_for(lambda: find_status(c), 120)
    await c.type_into("Code", CONTROLLER)
    target = await c.element("Run on", "GuiDropdownMessage", 120)
    await c.wait_for(lambda: student.robot in (target.props.get("options") or ()), 120)
    target.value = student.robot
    await c.send(
        {"type": "GuiUpdateMessage", "uuid": target.uuid, "updates": {"value": student.robot}}
    )


async def work(student: Student, until: float, pace: tuple[float, float]) -> None:
    try:
        await _work(student, until, pace)
    except ConnectionError as exc:  # the viewer dropped this page: said, the class goes on
        student.errors.append(f"connection lost: {exc}")
        student.dropped = True


async def _work(student: Student, until: float, pace: tuple[float, float]) -> None:
    c = student.client
    step = 0
    running = False
    while time.monotonic() < until:
        await asyncio.sleep(random.uniform(*pace))
        action = ACTIONS[step % len(ACTIONS)]
        step += 1
        before = student.said()
        if running and ("cancelled" in before or "refused" in before):
            student.lost.append(before)  # ended before this student pressed Stop
            running = False
        clicked = time.monotonic()
        await c.click(action)

        def answered(before: str = before, action: str = action) -> bool:
            now = student.said()
            return now != before and ANSWERS[action](now)

        try:
            await c.wait_for(answered, 120)
        except TimeoutError:
            student.errors.append(f"{action}: no answer in 120 s (status {student.said()!r})")
            continue
        student.latencies[action].append(time.monotonic() - clicked)
        said = student.said()
        if action == "Run in simulation":
            running = "queued on" in said or "runs on" in said
            student.runs += running
        elif action == "Stop":
            running = False
        if "Not done" in said:
            student.errors.append(f"{action}: {said[:160]}")


async def run_class(
    url: str, students: int, seconds: float, pace: tuple[float, float]
) -> list[Student]:
    class_ = [Student(i, ViserClient(url, f"s{i:02d}"), f"k{i}") for i in range(students)]
    gate = asyncio.Semaphore(5)
    started = time.monotonic()
    await asyncio.gather(*(enter(s, gate) for s in class_))
    print(
        f"  the class is in: {students} students in {time.monotonic() - started:.0f} s", flush=True
    )
    until = time.monotonic() + seconds
    progress = asyncio.create_task(_progress(class_, until))
    await asyncio.gather(*(work(s, until, pace) for s in class_))
    progress.cancel()
    for s in class_:
        with contextlib.suppress(ConnectionError, OSError):
            await s.client.close()
    return class_


async def _progress(class_: list[Student], until: float) -> None:
    while True:
        await asyncio.sleep(30)
        done = sum(len(v) for s in class_ for v in s.latencies.values())
        left = max(0.0, until - time.monotonic())
        print(f"  {done} actions answered, {left:.0f} s to go", flush=True)


def report(args: argparse.Namespace, class_: list[Student], load0: float) -> None:
    load1 = os.getloadavg()[0]
    pace = f"{args.pace[0]:g}-{args.pace[1]:g} s"
    print(
        f"RESULTS a class of {args.students}, {args.seconds:.0f} s at an action every {pace}; "
        f"load {load0:.1f} -> {load1:.1f}"
    )
    for action in ACTIONS:
        values = [v for s in class_ for v in s.latencies[action]]
        worst = max(values, default=float("nan"))
        print(
            f"  {action:<18} {len(values):4d} answered  p50 {percentile(values, 0.5):5.2f} s  "
            f"p95 {percentile(values, 0.95):5.2f} s  max {worst:5.2f} s"
        )
    runs = sum(s.runs for s in class_)
    lost = [f"{s.user}: {x[:120]}" for s in class_ for x in s.lost]
    errors = [f"{s.user}: {x}" for s in class_ for x in s.errors]
    dropped = sum(s.dropped for s in class_)
    print(
        f"  runs started {runs}, lost {len(lost)}; unanswered or refused actions "
        f"{len(errors)}; pages dropped by the viewer {dropped}"
    )
    for line in (lost + errors)[:10]:
        print(f"    {line}")


def start_lab(lab: BenchLab, students: int, slot: float) -> str:
    """The lab's services for the class; the viewer's websocket address."""
    lab.start()
    plab = lab.lab
    assert plab is not None
    w = plab.wiring()
    w.maps_dir.mkdir(parents=True, exist_ok=True)
    class_map(w.maps_dir / "class.json", students)
    plab.account(wiring.service_account("engine", WORLD))
    engine = wiring.engine_spec(w, WORLD, w.maps_dir / "class.json", login=True)
    plab.start(engine, name="engine")
    plab.start_runner()
    plab.start_agent_context(ctx=ARENA, world=WORLD, slot=slot)
    port = free_port()
    viewer = ["viewer", "--http-port", str(port), "--id", "web"]
    lab.spawn([*viewer, "--data-dir", str(lab.tmp / "web"), *lab.net()], (AliveKind.VIEWER, "web"))
    print(f"  lab up: viewer on http://127.0.0.1:{port}", flush=True)
    return f"ws://127.0.0.1:{port}"


def main() -> None:
    p = bench_cli.parser("bench_class", __doc__)
    p.add_argument("--students", type=int, default=30, help="headless students (default 30)")
    p.add_argument("--seconds", type=float, default=240.0, help="working time (default 240)")
    p.add_argument(
        "--pace",
        type=float,
        nargs=2,
        default=(10.0, 20.0),
        metavar=("MIN", "MAX"),
        help="seconds between a student's actions (default 10 20)",
    )
    p.add_argument("--slot", type=float, default=600.0, help="the arena's slot length (s)")
    args = p.parse_args()
    if not 1 <= args.students <= 200:
        p.error("--students: 1 to 200")
    if not 0 < args.pace[0] <= args.pace[1]:
        p.error("--pace MIN MAX: 0 < MIN <= MAX")
    lab = BenchLab([f"s{i:02d}" for i in range(args.students)], PASSWORD)
    load0 = os.getloadavg()[0]
    print(f"a class of {args.students} on one lab, {os.cpu_count()} cores, load {load0:.2f}")
    try:
        url = start_lab(lab, args.students, args.slot)
        pace = (args.pace[0], args.pace[1])
        class_ = asyncio.run(run_class(url, args.students, args.seconds, pace))
    finally:
        lab.stop()
    report(args, class_, load0)


if __name__ == "__main__":
    main()
