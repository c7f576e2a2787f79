"""Grading a class: N students submit to one assignment within a window, E episodes each.

A real lab as processes (router, registry, one runner, the grader; tests/kit/lab.py
starts them with the lab's own command lines), a course of ``--students``
imported, and an assignment on the empty map (a goal zone, ``--seconds``
simulated s per episode, ``--episodes`` seeded episodes). Each student logs in
and submits tests/integration/grading/works.py at an even spread over
``--window`` s. Printed: episodes graded per minute (from the first submission
to the last score), the wait from submit to score (p50, p99, max: the grader's
own clock at both ends), and fairness (the longest wait over the median).

    .venv/bin/python -m bench.bench_grading --students 60 --episodes 3 --window 60
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench import cli as bench_cli
from common.client.grader_client import GraderClient
from common.client.lab_client import LabClient
from common.messages import SubmissionInfo
from common.service import close_session
from services.registry.roster import RosterRow
from tests.kit.courses import add_course, assignment_toml
from tests.kit.lab import PASSWORD, make_lab
from tests.kit.procs import Procs, start_router

REPO = Path(__file__).resolve().parent.parent


def pct(values: list[float], q: float) -> float:
    """The ``q`` quantile (0 to 1) of ``values``: the nearest of their sorted ranks."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("bench_grading", __doc__)
    p.add_argument("--students", type=int, default=60)
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--seconds", type=float, default=5.0, help="simulated s per episode")
    p.add_argument("--window", type=float, default=60.0, help="submissions spread over (s)")
    args = p.parse_args(argv)

    students = [f"s{i:03d}" for i in range(args.students)]
    source = (REPO / "tests" / "integration" / "grading" / "works.py").read_bytes()
    with tempfile.TemporaryDirectory(prefix="bench-grading-") as tmp:
        procs = Procs(Path(tmp), env={"WART_LOG_LEVEL": "WARNING"})
        try:
            router = start_router(procs, f"bg{int(time.time()) % 100000}")
            users = {**dict.fromkeys(students, "student"), "ida": "instructor"}
            lab = make_lab(router, procs, Path(tmp), users=users)
            rows = [RosterRow(line=n + 2, user=s, name=s) for n, s in enumerate(students)]
            rows.append(RosterRow(line=len(rows) + 2, user="ida", name="Ida", role="teacher"))
            text = assignment_toml(
                "bench",
                time_limit=f"{args.seconds:g}",
                episodes=str(args.episodes),
                quota="100",
                goal_x=700,
                goal_radius=80,
                rule='100 * reached("goal") - time_to("goal")',
            )
            add_course(lab.db_path, rows, text)
            lab.start_registry()
            lab.start_runner()
            lab.start_grader()
            session = lab.zsession()
            clients = []
            for s in students:  # logins first: the window measures grading, not argon2id
                client = LabClient(session, lab.realm, lab.identity.verify_key, presence=False)
                client.login(s, PASSWORD)
                clients.append(client)
            print(
                f"{len(students)} students logged in; submitting over {args.window:g} s", flush=True
            )
            subs: list[str] = []
            t0 = time.monotonic()
            for i, client in enumerate(clients):
                delay = t0 + i * args.window / max(1, len(clients)) - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                subs.append(GraderClient(client).submit("bench", source, "works.py").submission)
            teacher = LabClient(session, lab.realm, lab.identity.verify_key, presence=False)
            teacher.login("ida", PASSWORD)
            grader = GraderClient(teacher)
            done: dict[str, SubmissionInfo] = {}
            deadline = time.monotonic() + 3600
            while len(done) < len(subs) and time.monotonic() < deadline:
                for sub in subs:
                    if sub not in done:
                        found = grader.submissions("bench", submission=sub)
                        if found and found[0].status in ("graded", "failed"):
                            done[sub] = found[0]
                time.sleep(1.0)
            for client in [*clients, teacher]:
                client.close()
            close_session(session)
        finally:
            procs.stop_all()
    infos = list(done.values())
    waits = [x.graded_at - x.submitted_at for x in infos if x.graded_at]
    first = min(x.submitted_at for x in infos)
    last = max(x.graded_at or 0 for x in infos)
    episodes = sum(len(x.episodes) for x in infos)
    causes: dict[str, int] = {}
    for x in infos:
        for e in x.episodes:
            causes[e.cause] = causes.get(e.cause, 0) + 1
    median = statistics.median(waits)
    print(
        f"\n{len(infos)} submissions, {episodes} episodes of {args.seconds:g} simulated s "
        f"({', '.join(f'{k} {v}' for k, v in sorted(causes.items()))}) "
        f"in {last - first:.0f} s from the first submission to the last score"
    )
    print(f"episodes per minute: {episodes / (last - first) * 60:.1f}")
    print(
        f"submit to score: p50 {median:.1f} s, p99 {pct(waits, 0.99):.1f} s, "
        f"max {max(waits):.1f} s; fairness: max/median {max(waits) / median:.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
