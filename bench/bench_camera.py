"""The arena camera: how well it tracks, what each frame costs, what its subscribers get.

Part 0, a camera that is not ours (bench/camera_scenes.py): tilted 10 to 25 degrees,
barrel and pincushion lenses, 1280x720, robots driving at up to 320 mm/s with
motion blur, light changes, noise, JPEG and a hand; with the lens calibrated from
a ChArUco board by `wart camera calibrate --intrinsics`'s code, and without it.

Part 1, no network: a synthetic camera (640x480 by default, straight down from
1.5 m over a 1 m arena, blur and sensor noise) renders N robots at random poses;
the tracker's error against the true poses (p50, p99 in mm and degrees) and the
CPU of each step of a frame (render, track, JPEG, the floor view).

Part 2, real processes: a router, an engine (the world whose snapshot gives the
markers), ``wart camera`` on the synthetic source at ``--fps``, and K subscriber
sessions (in a few processes) on the camera's image key: frames a second and
bytes a second each got, the delay from capture to arrival (p50, p99; one clock),
and the camera process's CPU per frame.

    python -m bench.bench_camera [--scene-frames 90] [--frames 200] [--viewers 1 10 30]
        [--seconds 10]
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import psutil
import zenoh

from bench import camera_scenes
from bench import cli as bench_cli
from common import keys
from common.messages import CameraFrame, decode
from common.service import close_session, open_session
from common.tracking.calibration import calibrate
from common.tracking.markers import default_layout
from common.tracking.synthetic import CameraModel, SyntheticCamera
from common.tracking.tracker import Tracker
from common.tracking.truth import now_truth, write_truth
from common.zconfig import NetworkOptions

REPO = Path(__file__).resolve().parent.parent


def tracking_error(frames: int, robots: int, width: int, height: int, seed: int) -> None:
    agents = [f"k{i}" for i in range(robots)]
    layout = default_layout(1000, 1000, agents)
    model = CameraModel(width=width, height=height)
    camera = SyntheticCamera(
        1000, 1000, layout, model, blur_sigma_px=0.7, noise_sigma=3.0, seed=seed
    )
    cal = calibrate(camera.render({}), layout, camera_height_mm=model.height_mm)
    rng = np.random.default_rng(seed)
    mm, deg, seen = [], [], 0
    cost: dict[str, list[float]] = {"render": [], "track": [], "jpeg": [], "floor": []}
    h_floor = np.array([[0.5, 0, 0], [0, -0.5, 500], [0, 0, 1]]) @ cal.homography
    for i in range(frames):
        poses: dict[str, tuple[float, float, float]] = {}
        while len(poses) < robots:  # robots apart, as they are on a floor
            x, y = rng.uniform(110, 890, 2)
            if all(math.hypot(x - p[0], y - p[1]) > 70 for p in poses.values()):
                poses[agents[len(poses)]] = (
                    float(x),
                    float(y),
                    float(rng.uniform(-math.pi, math.pi)),
                )
        t0 = time.process_time()
        frame = camera.render(poses)
        t1 = time.process_time()
        found = Tracker(layout, cal).track(frame, float(i))
        t2 = time.process_time()
        cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 70])
        t3 = time.process_time()
        cv2.warpPerspective(frame, h_floor, (500, 500))
        t4 = time.process_time()
        for step, dt in zip(cost, (t1 - t0, t2 - t1, t3 - t2, t4 - t3), strict=True):
            cost[step].append(dt * 1000)
        for p in found.poses:
            x, y, h = poses[p.agent]
            mm.append(math.hypot(p.x - x, p.y - y))
            deg.append(math.degrees(abs((p.heading - h + math.pi) % (2 * math.pi) - math.pi)))
            seen += 1
    print(
        f"tracking at {width}x{height}, {robots} robots a frame: {seen} of {frames * robots} seen"
    )
    print(
        f"  position error p50 {np.percentile(mm, 50):.2f} mm, p99 {np.percentile(mm, 99):.2f} mm "
        f"(targets 3 and 8); heading p50 {np.percentile(deg, 50):.2f} deg, p99 "
        f"{np.percentile(deg, 99):.2f} deg (targets 1 and 3)"
    )
    print(
        "  CPU ms a frame, median: " + ", ".join(f"{k} {np.median(v):.1f}" for k, v in cost.items())
    )


def subscribe(connect: str, realm: str, key: str, sessions: int, seconds: float) -> None:
    """A subscriber process: ``sessions`` sessions on ``key``; prints one JSON line each."""

    # Counted from 1 s after every session is open to 1 s before the end.
    stats: list[dict[str, Any]] = [{"frames": 0, "bytes": 0, "delays": []} for _ in range(sessions)]
    window = [0.0, 0.0]
    opened = []
    for s in stats:
        session = open_session(NetworkOptions(realm=realm, connect=(connect,)), wait=10.0)

        def on(sample: zenoh.Sample, s: dict[str, Any] = s) -> None:
            payload = bytes(sample.payload)
            frame = decode(payload, CameraFrame)
            if not window[0] <= time.time() < window[1]:
                return
            s["frames"] += 1
            s["bytes"] += len(payload)
            s["delays"].append(time.time() - frame.captured_at)

        opened.append((session, session.declare_subscriber(key, on)))
    window[:] = [time.time() + 1.0, time.time() + seconds - 1.0]
    time.sleep(seconds)
    for session, sub in opened:
        sub.undeclare()
        close_session(session)
    for s in stats:
        print(json.dumps(s), flush=True)


def delivery(viewers: list[int], seconds: float, fps: float) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="wart-bench-camera-"))
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    realm, world = "bench", "w1"
    endpoint = f"tcp/127.0.0.1:{port}"
    net = ["--realm", realm, "--connect", endpoint, "--no-multicast-scouting"]
    env = {**os.environ, "PYTHONPATH": str(REPO), "WART_LOG_LEVEL": "WARNING"}
    truth = tmp / "truth.json"
    stop = threading.Event()

    def write() -> None:
        t = 0.0
        while not stop.wait(0.05):
            t += 0.05
            write_truth(
                truth,
                now_truth(
                    1000,
                    1000,
                    {
                        "k1": (
                            500 + 300 * math.cos(t / 3),
                            500 + 300 * math.sin(t / 3),
                            t / 3 + math.pi / 2,
                        )
                    },
                ),
            )

    write_truth(truth, now_truth(1000, 1000, {"k1": (800.0, 500.0, math.pi / 2)}))
    threading.Thread(target=write, daemon=True).start()

    def start(*args: str) -> subprocess.Popen[bytes]:
        return subprocess.Popen([sys.executable, "-m", "services.cli", *args], cwd=REPO, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip

    procs = [start("router", "--realm", realm, "--listen", endpoint, "--no-multicast-scouting")]
    time.sleep(1.0)
    # A copy: an engine journals its live edits beside its map, here not in the checkout.
    empty = shutil.copy(REPO / "maps" / "empty.json", tmp / "empty.json")
    procs.append(start("engine", "--map", str(empty), "--world", world, *net))
    camera = start(
        "camera",
        "--world",
        world,
        "--source",
        f"synthetic:{truth}",
        "--auto-calibrate",
        "--fps",
        f"{fps:g}",
        *net,
    )
    procs.append(camera)
    key = keys.camera_frame(realm, world, f"{world}-cam")
    try:
        time.sleep(8.0)  # the engine up, the camera calibrated
        for count in viewers:
            per_proc = 10
            subs = []
            for start_at in range(0, count, per_proc):
                n = min(per_proc, count - start_at)
                argv = ["--subscriber", endpoint, realm, key, str(n), f"{seconds:g}"]
                subs.append(subprocess.Popen(
                    [sys.executable, "-m", "bench.bench_camera", *argv],
                    cwd=REPO, env=env, stdout=subprocess.PIPE, text=True,
                ))  # fmt: skip
            cam = psutil.Process(camera.pid)
            time.sleep(1.0)  # sessions open
            cpu0 = sum(cam.cpu_times()[:2])
            time.sleep(max(0.0, seconds - 2.0))
            cpu1 = sum(cam.cpu_times()[:2])
            results = []
            for p in subs:
                out, _ = p.communicate(timeout=seconds + 60)
                results += [json.loads(line) for line in out.splitlines() if line.startswith("{")]
            window = seconds - 2.0
            rates = [r["frames"] / window for r in results]
            rates_b = [r["bytes"] / window / 1024 for r in results]
            delays = [d * 1000 for r in results for d in r["delays"]]
            frames_made = fps * (seconds - 2.0)
            p50, p99 = np.percentile(delays, 50), np.percentile(delays, 99)
            print(
                f"{count:>3} subscribers: frames/s each min {min(rates):.1f} mean "
                f"{np.mean(rates):.1f}; {np.mean(rates_b):.0f} KiB/s each; capture to arrival "
                f"p50 {p50:.1f} ms, p99 {p99:.1f} ms; camera CPU "
                f"{1000 * (cpu1 - cpu0) / frames_made:.1f} ms a frame; "
                f"load {os.getloadavg()[0]:.1f}"
            )
    finally:
        stop.set()
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--subscriber"]:
        connect, realm, key, sessions, seconds = argv[1:6]
        subscribe(connect, realm, key, int(sessions), float(seconds))
        return 0
    p = bench_cli.parser("bench_camera", __doc__)
    p.add_argument(
        "--frames", type=int, default=200, help="frames for the tracking error (default 200)"
    )
    p.add_argument("--robots", type=int, default=4, help="robots in each frame (default 4)")
    p.add_argument(
        "--size", default="640x480", help="the synthetic camera's frame (default 640x480)"
    )
    p.add_argument(
        "--viewers",
        type=int,
        nargs="*",
        default=[1, 10, 30],
        help="subscriber counts (default 1 10 30)",
    )
    p.add_argument(
        "--seconds", type=float, default=10.0, help="seconds per subscriber count (default 10)"
    )
    p.add_argument("--fps", type=float, default=10.0, help="the camera's rate (default 10)")
    p.add_argument(
        "--scene-frames",
        type=int,
        default=90,
        help="frames of each tilted, distorting scene (default 90; 0 skips them)",
    )
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    if args.scene_frames:
        camera_scenes.report(args.scene_frames, args.seed)
    tracking_error(args.frames, args.robots, width, height, args.seed)
    if args.viewers:
        delivery(args.viewers, args.seconds, args.fps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
