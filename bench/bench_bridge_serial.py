"""Khepera bridge, serial side: sensor refresh rate and command latency against the emulator.

The emulator paces bytes at the baud rate (8N2: baud/11 bytes/s each way),
so the figures are what a host gets from a real robot's serial line, minus
the robot's own processing time (unknown; ``--reply-delay`` adds one). Beside
each figure: what the baud rate alone allows (bytes of the command and its
reply at baud/11 bytes/s).

    .venv/bin/python -m bench.bench_bridge_serial [--seconds 3] [--bauds 38400 9600]
"""

from __future__ import annotations

import statistics
import sys
import threading
import time
from typing import Any

from bench import cli as bench_cli
from services.bridge import protocol as P
from services.bridge.body import KinematicBody
from services.bridge.emulator import EmulatorOptions, KheperaEmulator
from services.bridge.link import SerialKheperaLink
from services.bridge.robot import KheperaRobot, RobotOptions


def wire_time(baud: int, *messages: bytes) -> float:
    return sum(len(m) for m in messages) / (baud / 11)


def body() -> KinematicBody:
    b = KinematicBody()
    # Four-digit readings: the longest replies, so the worst case.
    b.proximity_values = [1023, 1000, 999, 1010, 1001, 1002, 1003, 1004]
    b.ambient_values = [500] * 8
    return b


def latency(baud: int, n: int, reply_delay: float) -> dict[str, tuple[float, float, float]]:
    """Median and p95 round trip of single requests on an idle link, and the wire floor."""
    out: dict[str, tuple[float, float, float]] = {}
    opts = EmulatorOptions(baud=baud, pace=True, banner=False, reply_delay=reply_delay)
    with KheperaEmulator(body(), opts) as emu:
        link = SerialKheperaLink.open(emu.port, baud)
        try:
            cases: list[tuple[str, P.Request[Any], bytes]] = [
                ("D (set speed)", P.set_speed(0, 0), b"d\r\n"),
                (
                    "N (proximity)",
                    P.read_proximity(),
                    b"n,1023,1000,999,1010,1001,1002,1003,1004\r\n",
                ),
                ("H (counters)", P.read_counters(), b"h,0,0\r\n"),
            ]
            for name, req, reply in cases:
                samples = []
                for _ in range(n):
                    t0 = time.perf_counter()
                    link.request(req)
                    samples.append(time.perf_counter() - t0)
                samples.sort()
                out[name] = (
                    statistics.median(samples),
                    samples[int(0.95 * (len(samples) - 1))],
                    wire_time(baud, req.encode(), reply),
                )
        finally:
            link.close()
    return out


def refresh(
    baud: int, seconds: float, gripper: bool, reply_delay: float
) -> tuple[float, float, float]:
    """Sensor rounds per second polling flat out, set_speed latency under that load, wire floor."""
    opts = EmulatorOptions(baud=baud, pace=True, banner=False, reply_delay=reply_delay)
    with KheperaEmulator(body(), opts) as emu:
        robot_opts = RobotOptions(
            baud=baud, poll_interval=0.0, gripper=gripper, gripper_every=4, watchdog=5
        )
        with KheperaRobot(emu.port, robot_opts) as robot:
            if not robot.wait_online(5):
                raise SystemExit("emulated robot did not come online")
            lat: list[float] = []
            stop = threading.Event()

            def drive() -> None:
                while not stop.wait(0.05):
                    t0 = time.perf_counter()
                    robot.command(P.set_speed(0, 0)).result(2)
                    lat.append(time.perf_counter() - t0)

            driver = threading.Thread(target=drive)
            r0, t0 = robot.state().rounds, time.perf_counter()
            driver.start()
            time.sleep(seconds)
            r1, t1 = robot.state().rounds, time.perf_counter()
            stop.set()
            driver.join()
    per_round = [
        (b"N\r", b"n,1023,1000,999,1010,1001,1002,1003,1004\r\n"),
        (b"O\r", b"o,500,500,500,500,500,500,500,500\r\n"),
        (b"H\r", b"h,0,0\r\n"),
        (b"E\r", b"e,0,0\r\n"),
    ]
    floor = sum(wire_time(baud, c, r) for c, r in per_round)
    if gripper:
        grip = [
            (b"T,1,H,1\r", b"t,1,h,165\r\n"),
            (b"T,1,H,0\r", b"t,1,h,0\r\n"),
            (b"T,1,G\r", b"t,1,g,0\r\n"),
        ]
        floor += sum(wire_time(baud, c, r) for c, r in grip) / 4
    # The driver's D commands share the wire: 20 per second. (Zero speeds keep
    # the counters at 0, so the reply lengths above are exact.)
    floor_rate = (1 - 20 * wire_time(baud, b"D,0,0\r", b"d\r\n")) / floor
    return (r1 - r0) / (t1 - t0), statistics.median(lat), floor_rate


def main() -> int:
    ap = bench_cli.parser("bench_bridge_serial", __doc__)
    ap.add_argument("--seconds", type=float, default=3.0, help="polling time per configuration")
    ap.add_argument("--requests", type=int, default=100, help="requests per latency figure")
    ap.add_argument("--bauds", type=int, nargs="+", default=[38400, 9600])
    ap.add_argument("--reply-delay", type=float, default=0.0, help="robot think time per reply (s)")
    args = ap.parse_args()
    print(
        f"Khepera bridge serial benchmark (emulator paced at baud/11 bytes/s, reply delay "
        f"{args.reply_delay * 1000:.1f} ms)\n"
    )
    for baud in args.bauds:
        print(f"== {baud} baud ({baud / 11:.0f} bytes/s each way)")
        print(f"{'request':<16} {'median ms':>10} {'p95 ms':>8} {'wire-only ms':>13}")
        for name, (med, p95, floor) in latency(baud, args.requests, args.reply_delay).items():
            print(f"{name:<16} {med * 1000:>10.2f} {p95 * 1000:>8.2f} {floor * 1000:>13.2f}")
        print(f"{'polling':<24} {'rounds/s':>9} {'wire allows':>12} {'set_speed median ms':>20}")
        for gripper in (False, True):
            rate, lat, floor_rate = refresh(baud, args.seconds, gripper, args.reply_delay)
            label = "N,O,H,E" + (" + gripper/4" if gripper else "")
            print(f"{label:<24} {rate:>9.1f} {floor_rate:>12.1f} {lat * 1000:>20.2f}")
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
