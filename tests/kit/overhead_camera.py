"""A camera that is not the tracker's: a ray-casting renderer from the textbook pinhole model.

The tracker's own synthetic camera (common/tracking/synthetic.py) hangs straight
down through a perfect lens, so a tracker fitted to it can share its blind spots.
This one is written independently, with numpy only, from the pinhole model with
Brown-Conrady distortion that OpenCV documents (radial k1, k2, k3 and tangential
p1, p2): each output pixel is undistorted by fixed-point iteration, its ray cast
into the scene and intersected with the floor, the robots' top plates and
sides, hands held over the arena, or a ChArUco board held in front of the lens.
The camera hangs anywhere, tilted and rolled; a moving robot is smeared along
its motion over the exposure; lighting changes, sensor noise and JPEG are added
last. OpenCV is used only to draw the markers (cv2.aruco's dictionaries, the
same the tracker reads), to sample images and to encode JPEG.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from common.tracking.intrinsics import BoardSpec
from common.tracking.markers import MarkerLayout, marker_image

FLOOR_GREY = 200.0
WALL_GREY = 70.0
TABLE_GREY = 120.0
BODY_TOP_GREY = 50.0
BODY_SIDE_GREY = 35.0
HAND_GREY = 150.0
BOARD_BACKGROUND_GREY = 110.0
QUIET_CELLS = 1  # white cells around each marker
TEXTURE_PX_PER_MM = 2.0
TEXTURE_MARGIN_MM = 150.0  # the table beyond the arena's walls


@dataclass(frozen=True)
class Lens:
    """Intrinsics: focal lengths and principal point in pixels, distortion in OpenCV's order.

    The defaults are a 1280x720 webcam with mild barrel distortion; k1 > 0 gives a
    pincushion lens.
    """

    width: int = 1280
    height: int = 720
    fx: float = 1010.0
    fy: float = 1005.0
    cx: float = 646.0
    cy: float = 354.0
    k1: float = -0.16
    k2: float = 0.06
    p1: float = 0.0008
    p2: float = -0.0005
    k3: float = 0.0

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def coefficients(self) -> np.ndarray:
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Ideal normalised image coordinates (x/z, y/z) -> distorted ones."""
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_d: np.ndarray, iterations: int = 30) -> np.ndarray:
        """Distorted normalised coordinates -> ideal ones (the model has no closed inverse).

        Fixed-point iterations until a step moves no point by more than 1e-13 (1e-10
        pixels): for these lenses 11 to 14 of the ``iterations`` at most (over a whole
        supersampled frame, 8 million points, each iteration is a fifth of a second)."""
        x, y = xy_d[..., 0].copy(), xy_d[..., 1].copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
            dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
            dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
            x_next = (xy_d[..., 0] - dx) / radial
            y_next = (xy_d[..., 1] - dy) / radial
            step = max(float(np.abs(x_next - x).max()), float(np.abs(y_next - y).max()))
            x, y = x_next, y_next
            if step <= 1e-13:
                break
        return np.stack([x, y], axis=-1)

    def pixel_rays(self, supersample: int) -> np.ndarray:
        """Each supersampled pixel's ideal normalised coordinates (x/z, y/z), read-only."""
        return _pixel_rays(self, supersample)

    def to_pixels(self, xy_d: np.ndarray) -> np.ndarray:
        return np.stack(
            [self.fx * xy_d[..., 0] + self.cx, self.fy * xy_d[..., 1] + self.cy], axis=-1
        )

    def from_pixels(self, uv: np.ndarray) -> np.ndarray:
        return np.stack(
            [(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], axis=-1
        )


# A lens's grid is the same for every camera made with it, and undistorting it is most of
# a camera's making (1280x720 supersampled twice: 3.7 million points, about two seconds):
# made once per lens in a process, it is shared read-only by every camera and board.
@functools.lru_cache(maxsize=4)
def _pixel_rays(lens: Lens, supersample: int) -> np.ndarray:
    s = supersample
    u = (np.arange(lens.width * s, dtype=np.float64) + 0.5) / s - 0.5
    v = (np.arange(lens.height * s, dtype=np.float64) + 0.5) / s - 0.5
    uu, vv = np.meshgrid(u, v)
    ideal = lens.undistort(lens.from_pixels(np.stack([uu, vv], axis=-1)))
    ideal.flags.writeable = False
    return ideal


@dataclass(frozen=True)
class Mount:
    """Where the camera hangs: ``height_mm`` above the floor, its optical axis through
    the floor point ``aim_mm``, tilted ``tilt_deg`` from vertical toward ``yaw_deg``
    (0: the camera stands at the arena's near side, -y, and looks toward +y), and
    rolled ``roll_deg`` about its axis."""

    height_mm: float = 1660.0
    tilt_deg: float = 18.0
    roll_deg: float = 1.5
    yaw_deg: float = 0.0
    aim_mm: tuple[float, float] = (500.0, 500.0)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, C): world -> camera rotation (rows: the camera's x, y, z axes) and centre."""
        tilt, yaw, roll = (math.radians(v) for v in (self.tilt_deg, self.yaw_deg, self.roll_deg))
        forward = np.array([-math.sin(yaw), math.cos(yaw), 0.0])  # horizontal look direction
        aim = np.array([self.aim_mm[0], self.aim_mm[1], 0.0])
        centre = aim - forward * self.height_mm * math.tan(tilt)
        centre[2] = self.height_mm
        z = aim - centre
        z /= np.linalg.norm(z)
        down = -forward  # the image's rows grow toward the near side
        y = down - (down @ z) * z
        if np.linalg.norm(y) < 1e-9:
            y = np.array([0.0, -1.0, 0.0])
        y /= np.linalg.norm(y)
        x = np.cross(y, z)
        c, s = math.cos(roll), math.sin(roll)
        x, y = c * x + s * y, -s * x + c * y
        return np.vstack([x, y, z]), centre


@dataclass(frozen=True)
class Robot:
    """A robot at the middle of the exposure, its velocity in mm/s and rad/s."""

    x: float
    y: float
    heading: float
    vx: float = 0.0
    vy: float = 0.0
    turn: float = 0.0


@dataclass(frozen=True)
class Hand:
    """Something held over the arena: a disc ``radius_mm`` wide at ``z_mm``."""

    x: float
    y: float
    z_mm: float = 250.0
    radius_mm: float = 70.0


@dataclass(frozen=True)
class Light:
    """Overall gain, a left-to-right gradient (fraction over the frame) and an offset."""

    gain: float = 1.0
    gradient: float = 0.0
    offset: float = 0.0


@dataclass
class Effects:
    exposure_s: float = 1.0 / 25.0
    defocus_px: float = 0.5
    noise_grey: float = 2.5
    jpeg_quality: int | None = 85
    light: Light = field(default_factory=Light)


def _marker_with_quiet_zone(marker: int, dictionary: int | None = None) -> np.ndarray:
    if dictionary is None:
        img = marker_image(marker, 6 * 20)
    else:
        img = cv2.aruco.generateImageMarker(
            cv2.aruco.getPredefinedDictionary(dictionary), marker, 120
        )
    pad = 20 * QUIET_CELLS
    return cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)


def _square(
    image: np.ndarray,
    cx: float,
    cy: float,
    heading: float,
    side: float,
    x: np.ndarray,
    y: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Values of a square ``image`` lying flat, centred at (cx, cy), its top edge toward
    ``heading``, ``side`` mm wide, at the points (x, y); and where the points fall on it."""
    up = (math.cos(heading), math.sin(heading))
    right = (math.sin(heading), -math.cos(heading))
    dx, dy = x - cx, y - cy
    a = (dx * right[0] + dy * right[1]) / side + 0.5
    b = 0.5 - (dx * up[0] + dy * up[1]) / side
    inside = (a >= 0) & (a < 1) & (b >= 0) & (b < 1)
    n = image.shape[0]
    values = cv2.remap(
        image.astype(np.float32),
        (a * n - 0.5).astype(np.float32),
        (b * n - 0.5).astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return values, inside


class OverheadCamera:
    """Renders an arena of robots with ArUco markers, as a tilted, distorting camera sees it."""

    def __init__(
        self,
        width_mm: float,
        height_mm: float,
        layout: MarkerLayout,
        lens: Lens | None = None,
        mount: Mount | None = None,
        *,
        supersample: int = 2,
        robot_radius_mm: float = 27.5,
        wall_mm: float = 12.0,
        seed: int = 0,
    ) -> None:
        self.width_mm, self.height_mm = width_mm, height_mm
        self.layout = layout
        self.lens = lens or Lens()
        self.mount = mount or Mount(aim_mm=(width_mm / 2.0, height_mm / 2.0))
        self.supersample = supersample
        self.robot_radius_mm = robot_radius_mm
        self._rng = np.random.default_rng(seed)
        self.rotation, self.centre = self.mount.pose()
        self._rays = self._cast_rays()
        self._markers = {i: _marker_with_quiet_zone(i) for i in layout.robots.values()}
        self._floor = self._render_floor(wall_mm)

    # -- geometry

    def project(self, points: np.ndarray) -> np.ndarray:
        """Image pixels (as the camera records them, distorted) of world points (x, y, z mm)."""
        cam = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.centre) @ self.rotation.T
        ideal = cam[:, :2] / cam[:, 2:3]
        return self.lens.to_pixels(self.lens.distort(ideal))

    def _cast_rays(self) -> np.ndarray:
        """Each supersampled pixel's ray in world axes (not normalised: its z is its scale)."""
        ideal = self.lens.pixel_rays(self.supersample)
        cam = np.concatenate([ideal, np.ones((*ideal.shape[:2], 1))], axis=-1)
        return (cam @ self.rotation).astype(np.float32)  # R^T applied to each row vector

    def _hit(self, rays: np.ndarray, z_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Where rays meet the plane at height ``z_mm`` (x, y arrays)."""
        t = (z_mm - self.centre[2]) / rays[..., 2]
        return self.centre[0] + t * rays[..., 0], self.centre[1] + t * rays[..., 1]

    # -- the floor: walls, table and the reference markers, drawn once

    def _render_floor(self, wall_mm: float) -> np.ndarray:
        k, m = TEXTURE_PX_PER_MM, TEXTURE_MARGIN_MM
        tw = math.ceil((self.width_mm + 2 * m) * k)
        th = math.ceil((self.height_mm + 2 * m) * k)
        col = (np.arange(tw) + 0.5) / k - m
        row = self.height_mm + m - (np.arange(th) + 0.5) / k
        xx, yy = np.meshgrid(col, row)
        tex = np.full((th, tw), TABLE_GREY, np.float32)
        inside = (xx >= 0) & (xx <= self.width_mm) & (yy >= 0) & (yy <= self.height_mm)
        # A floor is not flat grey: faint blotches, fixed by the seed.
        blotch = cv2.GaussianBlur(self._rng.normal(0, 14, (th, tw)).astype(np.float32), (0, 0), 12)
        tex[inside] = FLOOR_GREY + blotch[inside]
        wall = inside & (
            (xx < wall_mm)
            | (yy < wall_mm)
            | (xx > self.width_mm - wall_mm)
            | (yy > self.height_mm - wall_mm)
        )
        tex[wall] = WALL_GREY
        full = self.layout.reference_marker_mm * (6 + 2 * QUIET_CELLS) / 6.0
        half = full * math.sqrt(0.5)  # the square's reach, however it is turned
        for marker, (x, y) in self.layout.reference.items():
            # only the texels the marker can cover (the whole texture is 7 million)
            cols = slice(max(math.floor((x - half + m) * k), 0), math.ceil((x + half + m) * k) + 1)
            rows = slice(
                max(math.floor((self.height_mm + m - y - half) * k), 0),
                math.ceil((self.height_mm + m - y + half) * k) + 1,
            )
            image = _marker_with_quiet_zone(marker)
            values, on = _square(image, x, y, math.pi / 2, full, xx[rows, cols], yy[rows, cols])
            tex[rows, cols][on] = values[on]
        mx, my = self._hit(self._rays, 0.0)
        floor = cv2.remap(
            tex,
            ((mx + m) * k - 0.5).astype(np.float32),
            ((self.height_mm + m - my) * k - 0.5).astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=TABLE_GREY,
        )
        beyond = self._rays[..., 2] >= 0  # rays that never reach the floor
        floor[beyond] = TABLE_GREY
        return floor

    # -- frames

    def render(
        self,
        robots: Mapping[str, Robot],
        *,
        hands: Sequence[Hand] = (),
        effects: Effects | None = None,
    ) -> np.ndarray:
        """A BGR frame: each robot at its pose mid-exposure, smeared along its motion."""
        fx = effects or Effects()
        canvas = self._floor.copy()
        for agent, robot in robots.items():
            self._draw_robot(canvas, self.layout.robots.get(agent), robot, fx.exposure_s)
        for hand in hands:
            self._draw_hand(canvas, hand)
        return self._finish(canvas, fx)

    def _region(self, points: np.ndarray, pad_px: float = 3.0) -> tuple[slice, slice] | None:
        uv = self.project(points)
        s = self.supersample
        h, w = self._rays.shape[:2]
        x0 = max(int((uv[:, 0].min() - pad_px) * s), 0)
        x1 = min(int((uv[:, 0].max() + pad_px) * s) + 1, w)
        y0 = max(int((uv[:, 1].min() - pad_px) * s), 0)
        y1 = min(int((uv[:, 1].max() + pad_px) * s) + 1, h)
        if x1 <= x0 or y1 <= y0:
            return None
        return slice(y0, y1), slice(x0, x1)

    def _draw_robot(
        self, canvas: np.ndarray, marker: int | None, robot: Robot, exposure_s: float
    ) -> None:
        r = self.robot_radius_mm
        top = self.layout.robot_marker_height_mm
        half = exposure_s / 2.0
        ends = [(robot.x + robot.vx * t, robot.y + robot.vy * t) for t in (-half, half)]
        box = np.array(
            [
                (x + dx, y + dy, z)
                for x, y in ends
                for dx in (-r, r)
                for dy in (-r, r)
                for z in (0, top)
            ]
        )
        region = self._region(box)
        if region is None:
            return
        rays = self._rays[region]
        travel = self.project(np.array([[*ends[0], top], [*ends[1], top]]))
        blur_px = float(np.linalg.norm(travel[1] - travel[0])) + abs(robot.turn) * exposure_s * 20
        steps = max(1, math.ceil(blur_px * self.supersample))
        full = self.layout.robot_marker_mm * (6 + 2 * QUIET_CELLS) / 6.0
        heights = np.linspace(0.0, top, 8)
        planes = [self._hit(rays, z) for z in heights]
        background = canvas[region].copy()
        total = np.zeros_like(background)
        for i in range(steps):
            t = -half + exposure_s * (i + 0.5) / steps
            cx, cy = robot.x + robot.vx * t, robot.y + robot.vy * t
            heading = robot.heading + robot.turn * t
            layer = background.copy()
            side = np.zeros(layer.shape, bool)
            for px, py in planes[:-1]:
                side |= (px - cx) ** 2 + (py - cy) ** 2 <= r * r
            layer[side] = BODY_SIDE_GREY
            px, py = planes[-1]
            on_top = (px - cx) ** 2 + (py - cy) ** 2 <= r * r
            layer[on_top] = BODY_TOP_GREY
            if marker is not None:
                values, on = _square(self._markers[marker], cx, cy, heading, full, px, py)
                layer[on] = values[on]
            total += layer
        canvas[region] = total / steps

    def _draw_hand(self, canvas: np.ndarray, hand: Hand) -> None:
        r = hand.radius_mm
        box = np.array([(hand.x + dx, hand.y + dy, hand.z_mm) for dx in (-r, r) for dy in (-r, r)])
        region = self._region(box)
        if region is None:
            return
        px, py = self._hit(self._rays[region], hand.z_mm)
        on = (px - hand.x) ** 2 + (py - hand.y) ** 2 <= r * r
        canvas[region][on] = HAND_GREY

    def _finish(self, canvas: np.ndarray, fx: Effects) -> np.ndarray:
        return finish(canvas, self.lens, fx, self._rng, self.supersample)


def finish(
    canvas: np.ndarray, lens: Lens, fx: Effects, rng: np.random.Generator, supersample: int
) -> np.ndarray:
    """Supersampled radiance -> the frame a sensor gives: light, defocus, noise, JPEG."""
    img = cv2.resize(canvas, (lens.width, lens.height), interpolation=cv2.INTER_AREA)
    light = fx.light
    if light.gain != 1.0 or light.gradient or light.offset:
        ramp = 1.0 + light.gradient * (np.arange(lens.width, dtype=np.float32) / lens.width - 0.5)
        img = np.asarray(img * light.gain * ramp[None, :] + light.offset, dtype=np.float32)
    if fx.defocus_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), fx.defocus_px)
    if fx.noise_grey > 0:
        noise = np.asarray(rng.normal(0.0, fx.noise_grey, img.shape), dtype=np.float32)
        img = img + noise
    gray = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    bgr = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    if fx.jpeg_quality is not None:
        ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, fx.jpeg_quality])
        assert ok
        bgr = cv2.imdecode(data, cv2.IMREAD_COLOR)
    return np.asarray(bgr)


# -- a ChArUco board held in front of the lens, for intrinsic calibration


def printed(board: BoardSpec, px_per_mm: float = 4.0) -> np.ndarray:
    """The board as printed, with a white margin of half a square each side."""
    size = (
        round(board.columns * board.square_mm * px_per_mm),
        round(board.rows * board.square_mm * px_per_mm),
    )
    image = board.charuco().generateImage(size, marginSize=0, borderBits=1)
    pad = round(board.square_mm * px_per_mm / 2)
    return cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)


class BoardCamera:
    """The same lens photographing a ChArUco board held at a pose (board -> camera)."""

    def __init__(
        self, lens: Lens, board: BoardSpec, *, supersample: int = 2, seed: int = 0
    ) -> None:
        self.lens, self.board, self.supersample = lens, board, supersample
        self._rng = np.random.default_rng(seed)
        self._px_per_mm = 4.0
        self._image = printed(board, self._px_per_mm).astype(np.float32)
        ideal = lens.pixel_rays(supersample).astype(np.float32)
        # Each supersampled pixel's ray (x/z, y/z, 1) in the camera's axes, made once.
        self._rays = np.concatenate([ideal, np.ones((*ideal.shape[:2], 1), np.float32)], -1)

    def pose_toward(
        self,
        u: float,
        v: float,
        distance_mm: float,
        tilt_x_deg: float,
        tilt_y_deg: float,
        spin_deg: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """A board pose (R, t) whose centre is seen at pixel (u, v) ``distance_mm`` away."""
        ax, ay, az = (math.radians(a) for a in (tilt_x_deg, tilt_y_deg, spin_deg))
        rx = np.array(
            [[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]]
        )
        ry = np.array(
            [[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]]
        )
        rz = np.array(
            [[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]]
        )
        rotation = rx @ ry @ rz
        direction = np.array(
            [(u - self.lens.cx) / self.lens.fx, (v - self.lens.cy) / self.lens.fy, 1.0]
        )
        middle = np.array([self.board.columns, self.board.rows, 0.0]) * self.board.square_mm / 2.0
        return rotation, direction * distance_mm - rotation @ middle

    def render(
        self, rotation: np.ndarray, translation: np.ndarray, effects: Effects | None = None
    ) -> np.ndarray:
        fx = effects or Effects(exposure_s=0.0)
        normal = rotation[:, 2]
        origin = np.asarray(translation, dtype=np.float64).ravel()
        rays = self._rays
        depth = float(normal @ origin) / (rays @ normal.astype(np.float32))
        # The ray's hit on the board (rays * depth - origin) in the board's x and y axes,
        # without making the hit points themselves.
        bx = depth * (rays @ rotation[:, 0].astype(np.float32)) - np.float32(
            origin @ rotation[:, 0]
        )
        by = depth * (rays @ rotation[:, 1].astype(np.float32)) - np.float32(
            origin @ rotation[:, 1]
        )
        k = self._px_per_mm
        pad = round(self.board.square_mm * k / 2)
        canvas = cv2.remap(
            self._image,
            (bx * k + pad - 0.5).astype(np.float32),
            (by * k + pad - 0.5).astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=BOARD_BACKGROUND_GREY,
        )
        canvas[depth <= 0] = BOARD_BACKGROUND_GREY
        return finish(canvas, self.lens, fx, self._rng, self.supersample)

    def views(self, count: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
        """Poses a careful person holds a board at: over the whole frame, near and far,
        turned up to 40 degrees each way."""
        rng = np.random.default_rng(seed)
        out = []
        for _ in range(count):
            u = rng.uniform(0.12, 0.88) * self.lens.width
            v = rng.uniform(0.15, 0.85) * self.lens.height
            out.append(
                self.pose_toward(
                    float(u),
                    float(v),
                    float(rng.uniform(520, 1400)),
                    float(rng.uniform(-40, 40)),
                    float(rng.uniform(-40, 40)),
                    float(rng.uniform(-20, 20)),
                )
            )
        return out
