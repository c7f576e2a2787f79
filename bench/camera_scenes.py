"""Scenes from a camera that is not the tracker's (tests/kit/overhead_camera.py): how well the
tracker does on a tilted, distorting lens with blur, noise, light changes, JPEG and hands.

Each scene: the lens calibrated from rendered ChArUco views (``wart camera calibrate
--intrinsics``'s own code, not hand-written numbers), the arena calibrated from its
reference markers with and without those intrinsics, then robots driving at
several speeds (a hand over one of them every third frame); the tracker's error
against the truth at mid-exposure, its detection by speed over the frames where
the robot is not covered, and its CPU a frame.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from common.tracking.calibration import ArenaCalibration, calibrate
from common.tracking.intrinsics import BoardSpec, Intrinsics, IntrinsicsCollector
from common.tracking.markers import MarkerLayout, default_layout
from common.tracking.tracker import Tracker
from tests.kit.overhead_camera import (
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
        Mount(height_mm=1700.0, tilt_deg=25.0, roll_deg=-2.0, yaw_deg=8.0),
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
            f"CPU {np.median(self.cpu_ms):.1f} ms a frame "
            f"(p95 {np.percentile(self.cpu_ms, 95):.0f}; load {os.getloadavg()[0]:.1f})"
        )


def calibrated_lens(lens: Lens, views: int = 50, seed: int = 3) -> Intrinsics:
    """The lens as `wart camera calibrate --intrinsics` finds it from rendered board views."""
    camera = BoardCamera(lens, BoardSpec(), seed=seed)
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


@dataclass
class Drive:
    """A robot driving straight at a constant speed, turning back at the arena's walls."""

    robot: Robot

    def step(self, dt: float, rng: np.random.Generator) -> Robot:
        r = self.robot
        x, y, vx, vy = r.x + r.vx * dt, r.y + r.vy * dt, r.vx, r.vy
        if not 110 < x < 890:
            vx = -vx
        if not 110 < y < 890:
            vy = -vy
        heading = r.heading + float(rng.normal(0, 0.05))
        self.robot = Robot(min(max(x, 110), 890), min(max(y, 110), 890), heading, vx, vy)
        return self.robot


def drives(rng: np.random.Generator, agents: Sequence[str], speeds: Sequence[float]) -> list[Drive]:
    out: list[Drive] = []
    for k in range(len(agents)):
        speed = speeds[k % len(speeds)]
        way = float(rng.uniform(-math.pi, math.pi))
        x, y = rng.uniform(150, 850, 2)
        heading = float(rng.uniform(-math.pi, math.pi))
        out.append(
            Drive(Robot(float(x), float(y), heading, speed * math.cos(way), speed * math.sin(way)))
        )
    return out


def effects_for(rng: np.random.Generator) -> Effects:
    """A lab's frames: 1/25 s exposure, light that drifts, noise, JPEG at 85."""
    light = Light(
        gain=float(rng.uniform(0.75, 1.15)),
        gradient=float(rng.uniform(-0.25, 0.25)),
        offset=float(rng.uniform(-10, 10)),
    )
    return Effects(exposure_s=1 / 25, defocus_px=0.6, noise_grey=3.0, jpeg_quality=85, light=light)


def covers(camera: OverheadCamera, hand: Hand, robot: Robot, layout: MarkerLayout) -> bool:
    """Whether the hand is on the way from the camera to any corner of the robot's marker
    (its quiet zone included, with a margin: a robot next to the one under the hand may
    be covered too)."""
    half = layout.robot_marker_mm * 0.75
    top = layout.robot_marker_height_mm
    c = camera.centre
    for dx in (-half, half):
        for dy in (-half, half):
            corner = np.array([robot.x + dx, robot.y + dy, top])
            at = c + (corner - c) * (hand.z_mm - c[2]) / (top - c[2])
            if math.hypot(at[0] - hand.x, at[1] - hand.y) <= hand.radius_mm + 5.0:
                return True
    return False


def run_scene(
    scene: Scene, frames: int, seed: int, *, fps: float = 15.0, hands: bool = True
) -> dict[str, Figures]:
    """Robots driving for ``frames`` frames at ``fps``, tracked as the camera service
    tracks them (one Tracker a calibration, its history kept); every third frame a hand
    covers one robot, and robots drive through each other (the renderer has no
    collisions): covered robots are left out of the figures."""
    agents = [f"k{i}" for i in range(1, 1 + 2 * len(SPEEDS_MM_S))]
    layout = default_layout(1000, 1000, agents)
    camera = OverheadCamera(1000, 1000, layout, scene.lens, scene.mount, seed=seed)
    lens = calibrated_lens(scene.lens, seed=seed + 3)
    cals = arena_calibrations(camera, layout, lens, scene.mount.height_mm)
    trackers = {name: Tracker(layout, cal, say=lambda _: None) for name, cal in cals.items()}
    out = {name: Figures() for name in cals}
    rng = np.random.default_rng(seed)
    fleet = drives(rng, agents, SPEEDS_MM_S)
    for i in range(frames):
        robots = {agent: d.step(1.0 / fps, rng) for agent, d in zip(agents, fleet, strict=True)}
        hidden = agents[(i // 3) % len(agents)] if hands and i % 3 == 0 else None
        over = [Hand(robots[hidden].x, robots[hidden].y)] if hidden else []
        frame = camera.render(robots, hands=over, effects=effects_for(rng))
        for name, tracker in trackers.items():
            figures = out[name]
            t0 = time.process_time()
            found = {p.agent: p for p in tracker.track(frame, i / fps).poses}
            figures.cpu_ms.append(1000 * (time.process_time() - t0))
            for agent, robot in robots.items():
                if any(covers(camera, hand, robot, layout) for hand in over) or any(
                    other != agent and math.hypot(o.x - robot.x, o.y - robot.y) < 75
                    for other, o in robots.items()
                ):
                    continue  # covered: by a hand, or by a robot driving over it
                tally = figures.seen.setdefault(round(math.hypot(robot.vx, robot.vy)), [0, 0])
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
    print(
        "  (each scene: 8 robots, 2 at each of 0, 100, 200 and 320 mm/s, 15 fps, 1/25 s "
        "exposure; detection over the frames where a robot is not covered)"
    )
