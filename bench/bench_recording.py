"""Does a recorder slow the engine's tick? And how big is a recording per minute?

For N robots (default 10 and 1,000) the engine's tick as the engine runs it
(obstacle avoidance, physics, sensing, the WorldFrame packed, encoded and put
on ``world/<w>/frame`` through a real router), timed over ``--ticks`` ticks
twice: with nobody subscribed but a viewer-like sink, then with a recorder
process subscribed that writes every frame to an MCAP file as an agent
context does (common/recording/: JSON + zstd). Prints the median and p95
tick cost (CPU and wall ms) of both, and the recording's size per minute at
the engine's 50 frames a second. The recorder runs in its own process (as
in the lab: the context is another process), on the same machine, so the
figure includes its competition for the CPU. Figures go to docs/BENCHMARKS.md.

    .venv/bin/python -m bench.bench_recording [--sizes 10 1000] [--ticks 500]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import zenoh

from bench import cli as bench_cli
from bench.engine_bench import build, control
from bench.labproc import REPO, BenchLab
from common import keys
from common.messages import WorldFrame, decode, encode
from common.recording import schema as s
from common.recording.writer import RecordingWriter, frame_record
from common.service import close_session, has_subscribers, open_session
from common.world import packing
from common.zconfig import NetworkOptions

WORLD = "bench"
FRAME_HZ = 50  # the engine publishes a frame each 20 ms tick


def record(connect: str, n: int, out: Path) -> int:
    """The recorder process: every frame of WORLD into ``out`` until SIGTERM."""

    rows = [f"k{i}" for i in range(n)]
    now = time.time()
    info = s.RunInfo(
        ctx="bench", world=WORLD, agent="k0", user="bench", request_id="bench-1",
        mode="deploy", start=now, planned_end=now + 60,
    )  # fmt: skip
    writer = RecordingWriter(out, info)
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    session = open_session(NetworkOptions(realm="bench", connect=(connect,)), wait=10.0)
    sub = session.declare_subscriber(
        keys.world_frame("bench", WORLD), zenoh.handlers.FifoChannel(4096)
    )
    frames = 0
    print("ready", flush=True)
    while not stop[0]:
        sample = sub.try_recv()
        if sample is None:
            time.sleep(0.002)
            continue
        frame = decode(sample.payload, WorldFrame)
        writer.write(s.FRAME, frame_record(frame, rows, n))
        frames += 1
    writer.finish(s.RunEnd(status="finished", reason="bench over", at=time.time()))
    close_session(session)
    print(f"frames {frames}", flush=True)
    return 0


def ticks(n: int, count: int, session: zenoh.Session) -> tuple[list[float], list[float]]:
    """CPU and wall ms of ``count`` engine ticks with their frame published."""
    world = build(n)
    pub = session.declare_publisher(keys.world_frame("bench", WORLD))
    cpu, wall = [], []
    for _ in range(20):  # warm up (numba kernels, the route)
        control(world)
        world.step()
        pub.put(encode(packing.frame(world)))
    for _ in range(count):
        c0, w0 = time.process_time(), time.perf_counter()
        control(world)
        world.step()
        pub.put(encode(packing.frame(world)))
        cpu.append((time.process_time() - c0) * 1000)
        wall.append((time.perf_counter() - w0) * 1000)
        time.sleep(max(0.0, 0.02 - (time.perf_counter() - w0)))  # paced like the engine
    pub.undeclare()
    return cpu, wall


def _p95(xs: list[float]) -> float:
    return sorted(xs)[int(len(xs) * 0.95) - 1]


def main() -> None:
    p = bench_cli.parser("bench_recording", __doc__)
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 1000])
    p.add_argument("--ticks", type=int, default=500)
    p.add_argument("--record", nargs=3, metavar=("CONNECT", "N", "OUT"), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.record:
        sys.exit(record(args.record[0], int(args.record[1]), Path(args.record[2])))
    lab = BenchLab([], "x")
    lab.start_router()
    listen = lab.options.connect[0]  # where the recording child connects
    session = open_session(lab.options, wait=20.0)
    try:
        print(f"{'robots':>7} {'recorder':>9} {'cpu ms p50':>11} {'p95':>6} "
              f"{'wall ms p50':>12} {'p95':>6} {'MB/min':>8}")  # fmt: skip
        for n in args.sizes:
            cpu, wall = ticks(n, args.ticks, session)
            row = f"{n:>7} {'no':>9} {statistics.median(cpu):>11.2f} {_p95(cpu):>6.2f}"
            print(f"{row} {statistics.median(wall):>12.2f} {_p95(wall):>6.2f} {'-':>8}")
            out = lab.tmp / f"rec{n}.mcap"
            env = {**os.environ, "PYTHONPATH": str(REPO), "WART_LOG_LEVEL": "WARNING"}
            command = [sys.executable, "-m", "bench.bench_recording", "--record", listen]
            proc = subprocess.Popen(
                [*command, str(n), str(out)], cwd=REPO, env=env, stdout=subprocess.PIPE, text=True
            )
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == "ready"
            probe = session.declare_publisher(keys.world_frame("bench", WORLD))
            deadline = time.monotonic() + 10
            while not has_subscribers(probe) and time.monotonic() < deadline:
                time.sleep(0.05)  # wait on the condition: the recorder's subscription arrived
            probe.undeclare()
            cpu, wall = ticks(n, args.ticks, session)
            proc.send_signal(signal.SIGTERM)
            tail, _ = proc.communicate(timeout=60)
            frames = int(tail.split()[-1])
            per_min = out.stat().st_size / max(1, frames) * FRAME_HZ * 60 / 1e6
            row = f"{n:>7} {'yes':>9} {statistics.median(cpu):>11.2f} {_p95(cpu):>6.2f}"
            print(f"{row} {statistics.median(wall):>12.2f} {_p95(wall):>6.2f} {per_min:>8.2f}"
                  f"   ({frames} frames recorded of {args.ticks + 20})")  # fmt: skip
    finally:
        close_session(session)
        lab.stop()


if __name__ == "__main__":
    main()
