"""What a teacher's grader function costs per episode (issue 36, item 2).

    .venv/bin/python -m bench.bench_grader_function --runs 5

The same graded episode (tests/integration/grading/works.py on the empty map, a goal
zone) run by services/runner/episode.py without and with the wobble grader
(tests/integration/grading/graders/wobble.py), in this process as a runner does; and
grade() alone on episode data of 10 and 60 simulated s. Prints the median and max wall
time of each (no lab: the sandbox and the world only).
"""

from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

from bench import cli as bench_cli
from common.messages import Episode
from services.runner.episode import run_episode
from services.runner.grader_run import episode_data, run_grader

REPO = Path(__file__).resolve().parents[1]
GRADING = REPO / "tests" / "integration" / "grading"


def episode(seconds: float, grader: bytes | None) -> Episode:
    data = json.loads((REPO / "maps" / "empty.json").read_text())
    data["zones"] = [{"id": "goal", "shape": "circle", "x": 700, "y": 500, "radius": 60}]
    return Episode(
        submission="bench", episode=0, user="bench", map=json.dumps(data), agent="k1", seed=1,
        x=300, y=500, heading=0.0, seconds=seconds, source=(GRADING / "works.py").read_bytes(),
        filename="works.py", grader=grader, grader_filename="wobble.py",
    )  # fmt: skip


def timed(fn: object, runs: int) -> list[float]:
    out = []
    for _ in range(runs):
        t = time.monotonic()
        fn()  # type: ignore[operator]
        out.append(time.monotonic() - t)
    return out


def say(what: str, times: list[float]) -> None:
    print(f"{what:<44} median {statistics.median(times):6.3f} s  max {max(times):6.3f} s")


def main() -> None:
    p = bench_cli.parser("bench_grader_function", __doc__)
    p.add_argument("--runs", type=int, default=5)
    args = p.parse_args()
    wobble = (GRADING / "graders" / "wobble.py").read_bytes()
    run_episode(episode(1.0, None))  # the kernels compiled once, as a runner's first episode
    say("episode of 5 s, no grader", timed(lambda: run_episode(episode(5.0, None)), args.runs))
    with_grader = timed(lambda: run_episode(episode(5.0, wobble)), args.runs)
    say("episode of 5 s, with the grader", with_grader)
    for seconds in (10, 60):
        n = int(seconds / 0.1) + 1
        data = episode_data(
            robot="k1", seed=1, time_limit=seconds, cause="ok", sim_seconds=seconds,
            distance_mm=0.0, samples=[[i * 0.1, 300.0, 500.0, 0.0] + [0] * 8 for i in range(n)],
            contacts=[], reached={}, delivered={}, collisions={}, zones={},
        )  # fmt: skip
        say(f"grade() alone on {seconds} s of data", timed(
            lambda data=data: run_grader(wobble, "wobble.py", data), args.runs))  # fmt: skip


if __name__ == "__main__":
    main()
