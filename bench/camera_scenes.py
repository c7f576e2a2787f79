"""Scenes from a camera that is not the tracker's (tests/kit/overhead_camera.py): how well the
tracker does on a tilted, distorting lens with blur, noise, light changes, JPEG and hands.

Each scene: the lens calibrated from rendered ChArUco views (``wart camera calibrate
--intrinsics``'s own code, not hand-written numbers), the arena calibrated from its
reference markers with and without those intrinsics, then robots at random poses
and speeds; the tracker's error against the truth at mid-exposure, its detection
by speed, and its CPU a frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from common.tracking.calibration import ArenaCalibration, calibrate
from common.tracking.intrinsics import BoardSpec, Intrinsics, IntrinsicsCollector
from common.tracking.markers import MarkerLayout, default_layout
from common.tracking.tracker import Tracker
from tests.kit.overhead_camera import (
    Board,
    BoardCamera,
    Effects,
    Hand,
    Lens,
    Light,
    Mount,
    OverheadCamera,
    Robot,
)

SPEEDS_MM_S = (0.0, 100.0, 200.0, 320.0)  # 320: about a Khepera IV's top speed


@dataclass(frozen=True)
class Scene:
    name: str
    lens: Lens
    mount: Mount


SCENES = (
    Scene("tilt 18, barrel", Lens(), Mount(tilt_deg=18.0, roll_deg=1.5)),
    Scene(
        "tilt 25, pincushion",
        Lens(k1=0.10, k2=-0.02, p1=-0.0006, p2=0.0004),
        Mount(height_mm=1500.0, tilt_deg=25.0, roll_deg=-2.0, yaw_deg=8.0),
    ),
    Scene("tilt 10, barrel", Lens(k1=-0.22, k2=0.08), Mount(height_mm=1800.0, tilt_deg=10.0)),
)


@dataclass
class Figures:
    position_mm: list[float] = field(default_factory=list)
    signed_mm: list[tuple[float, float]] = field(default_factory=list)
    heading_deg: list[float] = field(default_factory=list)
    seen: dict[int, list[int]] = field(default_factory=dict)  # speed -> [seen, shown]
    cpu_ms: list[float] = field(default_factory=list)

    def line(self) -> str:
        mm = np.array(self.position_mm) if self.position_mm else np.array([math.nan])
        bias = np.mean(self.signed_mm, axis=0) if self.signed_mm else (math.nan, math.nan)
        deg = np.array(self.heading_deg) if self.heading_deg else np.array([math.nan])
        seen = ", ".join(
            f"{speed:.0f} mm/s {100 * s / max(n, 1):.1f} %"
            for speed, (s, n) in sorted(self.seen.items())
        )
        return (
            f"position p50 {np.percentile(mm, 50):.2f} p99 {np.percentile(mm, 99):.2f} mm "
            f"(mean x {bias[0]:+.2f} y {bias[1]:+.2f}); heading p99 "
            f"{np.percentile(deg, 99):.2f} deg; detection {seen}; "
            f"CPU {np.median(self.cpu_ms):.1f} ms a frame"
        )


def calibrated_lens(lens: Lens, views: int = 50, seed: int = 3) -> Intrinsics:
    """The lens as `wart camera calibrate --intrinsics` finds it from rendered board views."""
    camera = BoardCamera(lens, Board(), seed=seed)
    collector = IntrinsicsCollector(BoardSpec())
    for rotation, translation in camera.views(views, seed=seed):
        collector.offer(camera.render(rotation, translation), consecutive=False)
    return collector.calibrate()


def arena_calibrations(
    camera: OverheadCamera, layout: MarkerLayout, lens: Intrinsics, camera_height_mm: float
) -> dict[str, ArenaCalibration]:
    frame = camera.render({})
    return {
        "with intrinsics": calibrate(
            frame,
            layout,
            camera_height_mm=camera_height_mm,
            camera_matrix=lens.camera_matrix,
            dist_coeffs=lens.dist_coeffs,
            lens=lens,
        ),
        "without": calibrate(frame, layout, camera_height_mm=camera_height_mm),
    }


def robots_at_speeds(
    rng: np.random.Generator, agents: Sequence[str], speeds: Sequence[float]
) -> dict[str, Robot]:
    robots: dict[str, Robot] = {}
    while len(robots) < len(agents):
        x, y = rng.uniform(110, 890, 2)
        if all(math.hypot(x - r.x, y - r.y) > 80 for r in robots.values()):
            speed = speeds[len(robots) % len(speeds)]
            way = rng.uniform(-math.pi, math.pi)
            robots[agents[len(robots)]] = Robot(
                float(x),
                float(y),
                float(rng.uniform(-math.pi, math.pi)),
                vx=speed * math.cos(way),
                vy=speed * math.sin(way),
            )
    return robots


def effects_for(rng: np.random.Generator) -> Effects:
    """A lab's frames: 1/25 s exposure, light that drifts, noise, JPEG at 85."""
    light = Light(
        gain=float(rng.uniform(0.75, 1.15)),
        gradient=float(rng.uniform(-0.25, 0.25)),
        offset=float(rng.uniform(-10, 10)),
    )
    return Effects(exposure_s=1 / 25, defocus_px=0.6, noise_grey=3.0, jpeg_quality=85, light=light)


def run_scene(scene: Scene, frames: int, seed: int, *, hands: bool = True) -> dict[str, Figures]:
    agents = [f"k{i}" for i in range(1, 1 + 2 * len(SPEEDS_MM_S))]
    layout = default_layout(1000, 1000, agents)
    camera = OverheadCamera(1000, 1000, layout, scene.lens, scene.mount, seed=seed)
    lens = calibrated_lens(scene.lens, seed=seed + 3)
    cals = arena_calibrations(camera, layout, lens, scene.mount.height_mm)
    out = {name: Figures() for name in cals}
    rng = np.random.default_rng(seed)
    for i in range(frames):
        robots = robots_at_speeds(rng, agents, SPEEDS_MM_S)
        hidden = agents[i % len(agents)] if hands and i % 3 == 0 else None
        over = [Hand(robots[hidden].x, robots[hidden].y)] if hidden else []
        frame = camera.render(robots, hands=over, effects=effects_for(rng))
        for name, cal in cals.items():
            figures = out[name]
            t0 = time.process_time()
            poses = Tracker(layout, cal).detect_poses(frame, float(i))
            figures.cpu_ms.append(1000 * (time.process_time() - t0))
            found = {p.agent: p for p in poses}
            for agent, robot in robots.items():
                speed = round(math.hypot(robot.vx, robot.vy))
                tally = figures.seen.setdefault(speed, [0, 0])
                if agent == hidden:
                    continue
                tally[1] += 1
                pose = found.get(agent)
                if pose is None:
                    continue
                tally[0] += 1
                dx, dy = pose.x - robot.x, pose.y - robot.y
                figures.position_mm.append(math.hypot(dx, dy))
                figures.signed_mm.append((dx, dy))
                turn = (pose.heading - robot.heading + math.pi) % (2 * math.pi) - math.pi
                figures.heading_deg.append(math.degrees(abs(turn)))
    return out


def report(frames: int, seed: int) -> None:
    for scene in SCENES:
        for name, figures in run_scene(scene, frames, seed).items():
            print(f"{scene.name}, {name}: {figures.line()}", flush=True)
