"""Two cameras over one long arena, one per half, as a lab sets them up: reference
markers at the corners and along the seam (--reference-grid 3x2), each camera
calibrating from the four it sees; the bridge fuses both.

The emulated Khepera (slipping wheels, so odometry alone drifts) drives across
the seam: in the overlap both cameras see it and the world shows one pose;
leaving the left camera's view, the right one holds it with no jump and it is
never "not seen". Then the camera that sees it dies: the robot is on odometry,
said so, and the other camera takes it again when it drives back into its view.
"""

from __future__ import annotations

import itertools
import json
import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from common import keys
from common.keys import AliveKind
from common.messages import TrackedPoses, WorldFrame, decode
from services.bridge.emulator import EmulatorOptions, KheperaEmulator
from services.bridge.simbody import SimBody
from services.lab.supervisor import AliveWatch
from tests.conftest import Procs, Router, wait_for
from tests.integration.test_bridge_camera import pose_from
from tests.kit.procs import Proc

WORLD, AGENT = "real1", "k1"
WIDTH, HEIGHT = 2000, 1000
START = (500.0, 500.0, 0.0)
# Each camera hangs over its half and 100 mm past the seam; it sees about 200 mm more
# each way (its view is 1.12 times the rectangle): an overlap of some 600 mm.
HALVES = {"left": "0,0,1100,1000", "right": "900,0,2000,1000"}
STEP_BACK_MM = 5.0  # the most the shown pose may fall back while the robot drives forward


@pytest.fixture
def truth(tmp_path: Path) -> Path:
    return tmp_path / "truth.json"


@pytest.fixture
def width() -> int:
    """The arena's length, mm (a test parametrized by ``width`` has a longer one)."""
    return WIDTH


@pytest.fixture
def body(truth: Path, tmp_path: Path, width: int) -> Iterator[SimBody]:
    arena = tmp_path / "long-arena.json"
    arena.write_text(
        json.dumps(
            {
                "format": "wart-map",
                "version": 1,
                "name": "long-arena",
                "arena": {"width": width, "height": HEIGHT},
                "agents": [
                    {"id": AGENT, "type": "khepera", "x": START[0], "y": START[1], "heading_deg": 0}
                ],
            }
        )
    )
    with SimBody.from_map(arena, seed=2, slip=0.03, truth=truth) as sim:
        yield sim


@pytest.fixture
def emulator(body: SimBody, tmp_path: Path) -> Iterator[KheperaEmulator]:
    with KheperaEmulator(body, EmulatorOptions(link_path=str(tmp_path / "khepera0"))) as emu:
        yield emu


class Follow:
    """The world's shown pose of the robot against the truth, and each camera's sightings."""

    def __init__(self, session: zenoh.Session, realm: str, body: SimBody) -> None:
        self.body = body
        self.lock = threading.Lock()
        self.truth: list[tuple[float, float, float]] = []  # (monotonic, x, y)
        self.shown: list[tuple[float, float, float]] = []
        self.sightings: dict[str, list[float]] = {}  # camera -> x of each sighting
        self._start = math.inf  # the bridge's start on this monotonic clock, at most
        self._made: list[float] = []  # each shown pose's frame stamp (the bridge's clock)
        self._subs = [
            session.declare_subscriber(keys.world_frame(realm, WORLD), self._on_frame),
            session.declare_subscriber(keys.world_tracked(realm, WORLD), self._on_tracked),
        ]

    def _on_frame(self, sample: zenoh.Sample) -> None:
        frame = decode(sample.payload, WorldFrame)
        x, y, _ = frame.poses.to_numpy()[0]
        arrived = time.monotonic()
        with self.lock:
            # The bridge stamps a frame on its monotonic clock from its start (the
            # machine's monotonic clock, as this one): arrival minus that stamp is its
            # start plus the frame's way here, the least of them its start plus the least
            # way. A frame is placed at when it was made, not when it came: a loaded
            # machine held some 0.3 s and more in its queues.
            self._start = min(self._start, arrived - frame.sim_time)
            self.shown.append((arrived, float(x), float(y)))
            self._made.append(frame.sim_time)

    def _on_tracked(self, sample: zenoh.Sample) -> None:
        seen = decode(sample.payload, TrackedPoses)
        with self.lock:
            for robot in seen.robots:
                self.sightings.setdefault(seen.camera, []).append(robot.x)

    def sample_truth(self, seconds: float) -> None:
        """The true pose every 20 ms for ``seconds`` (a sampling period, not a wait)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            x, y, _ = self.body.pose()
            with self.lock:
                self.truth.append((time.monotonic(), x, y))
            time.sleep(0.02)

    def drive_until(self, arrived: Callable[[float], bool], timeout: float = 30.0) -> None:
        """Sample the truth until the robot's x says it arrived (a loaded machine's
        emulator runs slower than real time: not a fixed time)."""
        deadline = time.monotonic() + timeout
        while not arrived(self.body.pose()[0]):
            assert time.monotonic() < deadline, f"the robot is still at {self.body.pose()}"
            self.sample_truth(0.1)

    def largest_step_back(self, since: float) -> float:
        """How far the shown x fell below the furthest it had shown, at most, since
        ``since`` (the robot driving toward +x)."""
        with self.lock:
            xs = [x for at, x, _ in self.shown if at >= since]
        furthest, back = -math.inf, 0.0
        for x in xs:
            furthest = max(furthest, x)
            back = max(back, furthest - x)
        return back

    def errors(self, since: float) -> list[tuple[float, float]]:
        """Each shown pose since ``since``: (true x, its distance to the true path over the
        400 ms before the bridge made its frame). The path runs through the samples of the
        truth, on to the first after the frame was made: a loaded machine's sampling
        thread stalls too, and a fresh pose 20 mm past the last sample taken before it is
        not 20 mm off."""
        with self.lock:
            truth = list(self.truth)
            shown = [
                (made + self._start, x, y)
                for (at, x, y), made in zip(self.shown, self._made, strict=True)
                if at >= since
            ]
        out = []
        for at, x, y in shown:
            near = [t for t in truth if at - 0.4 <= t[0] <= at]
            near += [t for t in truth if t[0] > at][:1]
            if near:
                points = [(t[1], t[2]) for t in near]
                path = list(itertools.pairwise(points)) or [(points[0], points[0])]
                out.append((near[-1][1], min(_to_segment((x, y), a, b) for a, b in path)))
        return out

    def latest_delivery(self, since: float) -> float:
        """The longest a frame took from the bridge to here since ``since`` (s)."""
        with self.lock:
            ways = [
                at - made - self._start
                for (at, _, _), made in zip(self.shown, self._made, strict=True)
                if at >= since
            ]
        return max(ways, default=0.0)


def _to_segment(p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    """The distance from ``p`` to the segment from ``a`` to ``b``."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    f = 0.0 if length2 == 0 else ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2
    f = min(max(f, 0.0), 1.0)
    return math.hypot(p[0] - (a[0] + f * dx), p[1] - (a[1] + f * dy))


def start_lab(
    router: Router,
    procs: Procs,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    emulator: KheperaEmulator,
    body: SimBody,
    parts: dict[str, str],
    grid: str,
    width: int,
) -> tuple[Proc, dict[str, Proc], Follow]:
    """The bridge over the emulated robot and one synthetic camera over each of ``parts``
    (name -> the rectangle it hangs over), each calibrated from the ``grid``'s reference
    markers it sees; returned once the world's pose of the robot is tracked."""
    net = router.net_args()
    realm_name = router.realm
    robot = f"{emulator.port}={AGENT}@{START[0]:g},{START[1]:g},0"
    arena = ["--arena-mm", str(width), str(HEIGHT)]
    bridge = procs.start("bridge", ["bridge", "--world", WORLD, "--port", robot, *arena, *net])
    assert alive_watch.wait(keys.alive(realm_name, AliveKind.WORLD, WORLD), 30.0), bridge.output()
    cameras = {
        part: procs.start(
            f"camera-{part}",
            [
                "camera",
                "--world",
                WORLD,
                "--name",
                f"{WORLD}-{part}",
                "--source",
                f"synthetic:{body.truth}",
                "--synthetic-over",
                over,
                "--reference-grid",
                grid,
                "--auto-calibrate",
                *net,
            ],
        )
        for part, over in parts.items()
    }
    follow = Follow(zsession, realm_name, body)
    for part, camera in cameras.items():
        wait_for(
            lambda proc=camera: "calibrated from the reference markers" in proc.output(),
            90.0,
            f"the {part} camera calibrated:\n{camera.output()}",
        )
    wait_for(lambda: pose_from(zsession, realm_name) == "tracked", 30.0, "poses from the cameras")
    return bridge, cameras, follow


LATE = "the camera's frames are late"


def crossing(follow: Follow, body: SimBody, bridge: Proc, to_x: float) -> bool:
    """Drive at 160 mm/s from where the robot stands to ``to_x``; the world's pose all the
    way within a few mm of the true path (while the cameras' sightings come in time), and
    never going back. True if the bridge said the cameras' frames came late meanwhile."""
    late_before = bridge.output().count(LATE)
    started = time.monotonic()
    body.set_speeds(20, 20)
    follow.drive_until(lambda x: x >= to_x)
    body.set_speeds(0, 0)
    follow.sample_truth(0.5)
    crossing = follow.errors(started)
    assert len(crossing) > 50, len(crossing)
    errors = sorted(e for _, e in crossing)
    median, p90, worst = errors[len(errors) // 2], errors[len(errors) * 9 // 10], errors[-1]
    back = follow.largest_step_back(started)
    late = follow.latest_delivery(started)
    print(
        f"crossing: error median {median:.1f}, p90 {p90:.1f}, worst {worst:.1f} mm; "
        f"largest step back {back:.1f} mm; a frame's way here {late:.2f} s at most"
    )
    assert median < 1.0 and p90 < 3.0, (median, p90, worst, late, crossing)
    # The worst pose within 15 mm, unless the bridge said the cameras fell behind: a
    # CPU-starved host's cameras sent sightings 0.5 to 1 s late, and the bridge showed
    # the slipping wheels' odometry meanwhile (69 mm off at worst, in a CI run) and said so.
    starved = bridge.output().count(LATE) > late_before
    if not starved:
        assert worst < 15.0, (median, p90, worst, late, crossing)
    # Driving forward, it is never shown going back further than the cameras' noise and
    # the slipping wheels' overshoot between two frames (a late frame or odometry reading
    # paired with the other's wrong time stepped it back 13 to 58 mm).
    assert back < STEP_BACK_MM, (back, follow.shown)
    return starved


def test_two_cameras_over_the_halves_hand_the_robot_over_at_the_seam(
    router: Router,
    procs: Procs,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    emulator: KheperaEmulator,
    body: SimBody,
) -> None:
    realm_name = router.realm
    bridge, cameras, follow = start_lab(
        router, procs, zsession, alive_watch, emulator, body, HALVES, "3x2", WIDTH
    )
    for camera in cameras.values():
        assert "reference markers 44 at (1000, 955), 45 at (1000, 45)" in camera.output()

    # Across the seam at 160 mm/s: from x 500 (the left camera's) to 1500 (the right's).
    # (Before, the right camera may have calibrated first: k1 not seen, rightly.)
    said_before = bridge.output().count(" is not seen")
    crossing(follow, body, bridge, 1500.0)
    left, right = follow.sightings[f"{WORLD}-left"], follow.sightings[f"{WORLD}-right"]
    assert max(left) > 1150 and min(right) < 850  # both saw it over the overlap
    assert body.pose()[0] > 1450 and max(left) < 1350  # ... and the left one lost it
    assert pose_from(zsession, realm_name) == "tracked"
    assert bridge.output().count(" is not seen") == said_before, bridge.output()

    # The right camera dies with the robot in its half only: odometry, said so; driving
    # back into the left camera's view, the left one takes it.
    cameras["right"].kill9()
    wait_for(
        lambda: pose_from(zsession, realm_name) == "odometry",
        20.0,
        f"odometry for k1 once its camera died:\n{bridge.output()}",
    )
    assert "k1: the camera that saw it has gone" in bridge.output()
    back = time.monotonic()
    body.set_speeds(-20, -20)
    follow.drive_until(lambda x: x <= 800.0)
    body.set_speeds(0, 0)
    wait_for(lambda: pose_from(zsession, realm_name) == "tracked", 10.0, "the left camera's")
    follow.sample_truth(0.5)
    returned = [e for x, e in follow.errors(back) if x < 1050]
    assert returned and max(returned[-5:]) < 5.0, returned
    assert bridge.output().count(" is not seen") == said_before, bridge.output()


@pytest.mark.parametrize("width", [3000])
def test_three_cameras_over_the_thirds_hand_the_robot_on_twice(
    router: Router,
    procs: Procs,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    emulator: KheperaEmulator,
    body: SimBody,
    width: int,
) -> None:
    # A 3 m arena, one camera over each third and 100 mm past each seam; a 4x2 grid of
    # reference markers puts two columns in each camera's view (x 45, 1015, 1985, 2955).
    thirds = {"a": "0,0,1100,1000", "b": "950,0,2050,1000", "c": "1900,0,3000,1000"}
    bridge, _, follow = start_lab(
        router, procs, zsession, alive_watch, emulator, body, thirds, "4x2", width
    )
    said_before = bridge.output().count(" is not seen")
    starved = crossing(follow, body, bridge, 2500.0)
    seen = {part: follow.sightings[f"{WORLD}-{part}"] for part in thirds}
    assert max(seen["a"]) > 1150 and min(seen["b"]) < 850  # the first seam, seen by both
    # ... and the second: each camera sees past its own rectangle (b's ends at 2050, c's
    # starts at 1900). Not "c by 1800": c's view starts near 1700, but a CPU-starved
    # camera reads fewer frames (a CI run: c's first sighting at 1803).
    assert max(seen["b"]) > 2100 and min(seen["c"]) < 1850
    assert max(seen["a"]) < 1400 and max(seen["b"]) < 2350 < body.pose()[0]
    assert pose_from(zsession, router.realm) == "tracked"
    # Never "not seen" on the way, unless the cameras were starved: frames 0.5 s late,
    # then none for a second, and the bridge said both, truly (a CI run beside a full suite).
    if not starved:
        assert bridge.output().count(" is not seen") == said_before, bridge.output()
