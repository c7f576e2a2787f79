"""World (mm, radians, origin lower-left) to viser (metres, quaternions), vectorised.

Everything the pump does per frame is one numpy pass here, shared by every
browser watching the same world: the per-browser cost is then only viser's
serialisation of two arrays.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

MM = 0.001  # metres per millimetre
CAMERA_FOV = math.radians(20.0)  # narrow: close to an orthographic top-down look
ROBOT_Z = 0.01  # robots drawn just above the floor (metres)

# Khepera I IR sensor bearings (radians, 0 = ahead, counter-clockwise positive):
# six at the front from left to right, two at the back (K-Team manual, fig. 3).
IR_BEARINGS = np.radians([90.0, 45.0, 10.0, -10.0, -45.0, -90.0, -170.0, 170.0]).astype(np.float32)
IR_RANGE_MM = 60.0  # beyond this a Khepera's IR reads (nearly) nothing
IR_MAX = 1023.0  # a Khepera's IR reading at contact
IR_RAY_MM = IR_RANGE_MM  # a ray's length at IR_MAX (drawn from the body's rim)
IR_STUB_MM = 4.0  # a ray at reading 0: enough to show the sensor's bearing
IR_LOW_RGB = np.array([235.0, 205.0, 60.0], np.float32)  # pale yellow: nothing seen
IR_HIGH_RGB = np.array([230.0, 0.0, 0.0], np.float32)  # red: something touching


def yaw_to_wxyz(theta: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Rotations about +z by ``theta`` as (N, 4) quaternions w, x, y, z."""
    half = np.asarray(theta, dtype=np.float32) * 0.5
    out = np.zeros((*half.shape, 4), np.float32)
    out[..., 0] = np.cos(half)
    out[..., 3] = np.sin(half)
    return out


def poses_to_viser(
    poses: npt.NDArray[np.float32], z: float = ROBOT_Z
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """(N, 3) x mm, y mm, theta rad to (positions (N, 3) metres, wxyzs (N, 4))."""
    positions = np.empty((len(poses), 3), np.float32)
    positions[:, :2] = poses[:, :2] * MM
    positions[:, 2] = z
    return positions, yaw_to_wxyz(poses[:, 2])


def viser_to_world(x: float, y: float) -> tuple[float, float]:
    """A viser point (metres) back to world millimetres."""
    return x / MM, y / MM


def wxyz_to_yaw(wxyz: npt.ArrayLike) -> float:
    """The rotation about z of a quaternion (the editor reads gizmos back with it)."""
    w, x, y, z = (float(v) for v in np.asarray(wxyz).reshape(4))
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def robot_at(
    ray_origin: tuple[float, float, float],
    ray_direction: tuple[float, float, float],
    positions: npt.NDArray[np.float32],
    radius_m: float,
) -> int | None:
    """The robot a click's ray lands on (index into ``positions``, metres), or None.

    The ray is met with the plane the robots are drawn in; the nearest robot whose
    disc (a little enlarged: a few-pixel target) holds that point is the one.
    """
    ox, oy, oz = ray_origin
    dx, dy, dz = ray_direction
    if len(positions) == 0 or abs(dz) < 1e-9:
        return None  # a ray along the floor meets no robot from above
    t = (ROBOT_Z - oz) / dz
    if t < 0:
        return None
    hit = np.array([ox + t * dx, oy + t * dy], np.float32)
    d2 = np.sum((positions[:, :2] - hit) ** 2, axis=1)
    index = int(np.argmin(d2))
    return index if d2[index] <= (1.5 * radius_m) ** 2 else None


# The canvas's width over its height when the browser has not said yet: a 1280x800
# laptop screen beside the docked panel (the canvas is what the 460 px panel leaves,
# 820x800; viewers/web/app.py).
ASSUMED_ASPECT = 1.0


def fit_aspect(reported: float) -> float:
    """The aspect to aim for: the browser's, but never wider than ASSUMED_ASPECT.

    A page can report its canvas before the panel has docked beside it (seen: a
    camera aimed for a canvas several times wider than the one drawn); aiming for
    a narrower canvas than the real one only leaves more floor around the arena.
    """
    return max(0.5, min(reported, ASSUMED_ASPECT))


def camera_height(width_mm: float, height_mm: float, aspect: float = ASSUMED_ASPECT) -> float:
    """How high (m) a camera with CAMERA_FOV (vertical) must be for the arena to fit a
    canvas ``aspect`` wide (width over height), with a 5% margin on each side."""
    half_tan = math.tan(CAMERA_FOV / 2)
    need_v = height_mm * MM * 1.1 / 2
    need_h = width_mm * MM * 1.1 / 2 / aspect
    return max(need_v, need_h) / half_tan


FOLLOW_DEADBAND_M = 0.002  # the follow camera ignores moves smaller than this (2 mm)


Vec3 = tuple[float, float, float]


def follow_camera(
    position: npt.ArrayLike,
    look_at: npt.ArrayLike,
    target_xy_m: npt.ArrayLike,
    deadband_m: float = FOLLOW_DEADBAND_M,
) -> tuple[Vec3, Vec3] | None:
    """The camera moved sideways so that it looks at ``target_xy_m``, or None if it does.

    Position and look-at shift by the same x/y offset: the height, the zoom and
    the orientation (top-down) stay what the student left them.
    """
    pos = np.asarray(position, np.float64).reshape(3)
    look = np.asarray(look_at, np.float64).reshape(3)
    target = np.asarray(target_xy_m, np.float64).reshape(-1)[:2]
    offset = target - look[:2]
    if not np.all(np.isfinite(offset)) or float(np.hypot(*offset)) < deadband_m:
        return None
    new_pos = (float(pos[0] + offset[0]), float(pos[1] + offset[1]), float(pos[2]))
    new_look = (float(target[0]), float(target[1]), float(look[2]))
    return new_pos, new_look


def robot_mesh(
    radius_m: float, height_m: float = 0.01, segments: int = 16
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]:
    """A flat disc with a raised nose wedge pointing along +x: a robot with its heading.

    One mesh for every robot (batched); 2 * segments + 3 triangles keeps 1,000
    instances cheap for software WebGL.
    """
    angles = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    rim = np.stack([np.cos(angles), np.sin(angles), np.zeros(segments)], 1) * radius_m
    bottom_centre = [[0.0, 0.0, 0.0]]
    top_centre = [[0.0, 0.0, height_m]]
    top_rim = rim + np.array([0.0, 0.0, height_m])
    nose_h = height_m * 1.5
    nose = [
        [radius_m * 0.95, 0.0, nose_h],
        [-radius_m * 0.2, radius_m * 0.45, nose_h],
        [-radius_m * 0.2, -radius_m * 0.45, nose_h],
    ]
    vertices = np.concatenate([bottom_centre, top_centre, rim, top_rim, nose]).astype(np.float32)
    faces: list[tuple[int, int, int]] = []
    r0, t0 = 2, 2 + segments
    for i in range(segments):
        j = (i + 1) % segments
        faces.append((1, t0 + i, t0 + j))  # top
        faces.append((r0 + i, r0 + j, t0 + j))  # side
        faces.append((r0 + i, t0 + j, t0 + i))
    n0 = 2 + 2 * segments
    faces.append((n0, n0 + 1, n0 + 2))
    return vertices, np.asarray(faces, np.uint32)


def swarm_disc_mesh(
    radius_m: float, height_m: float = 0.01, segments: int = 8
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]:
    """A swarm robot seen from above: the top of the disc only, ``segments`` triangles.

    The top-down camera never sees a side, and a swarm robot is a few pixels
    wide: 8 triangles instead of :func:`robot_mesh`'s 51 keep 10,000 instances
    within what software WebGL can draw.
    """
    angles = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    rim = np.stack([np.cos(angles), np.sin(angles), np.full(segments, height_m)], 1)
    rim[:, :2] *= radius_m
    vertices = np.concatenate([[[0.0, 0.0, height_m]], rim]).astype(np.float32)
    faces = [(0, 1 + i, 1 + (i + 1) % segments) for i in range(segments)]  # ccw from +z
    return vertices, np.asarray(faces, np.uint32)


def heading_mesh(
    radius_m: float, height_m: float = 0.01
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]:
    """A flat arrow pointing along +x, just above :func:`robot_mesh`'s nose wedge.

    Drawn as its own batched mesh (same positions and orientations as the
    bodies) so that it can have a colour of its own: from above, a wedge in the
    body's colour cannot be told from the body under flat lighting.
    """
    z = height_m * 1.7  # above the body (height_m) and its nose wedge (1.5 * height_m)
    vertices = np.array(
        [
            [radius_m * 0.9, 0.0, z],  # tip
            [-radius_m * 0.5, radius_m * 0.6, z],  # left wing
            [-radius_m * 0.1, 0.0, z],  # notch
            [-radius_m * 0.5, -radius_m * 0.6, z],  # right wing
        ],
        np.float32,
    )
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)  # counter-clockwise seen from +z
    return vertices, faces


def ir_segments(
    pose: npt.ArrayLike, ir: npt.ArrayLike, robot_radius_mm: float
) -> npt.NDArray[np.float32]:
    """(8, 2, 3) line segments (metres) for one robot's IR rays, from the body's rim.

    A ray grows with its reading (the issue's "rays that grow with the
    reading"): its length is proportional to the reading, IR_RAY_MM at the
    top of the scale (1023, something touching), never shorter than
    IR_STUB_MM so that every sensor's bearing stays visible. A long ray is a
    near obstacle, on the side where it is.
    """
    x, y, theta = (float(v) for v in np.asarray(pose).reshape(3))
    reading = ir_level(ir)
    length = np.maximum(IR_STUB_MM, IR_RAY_MM * reading)
    bearing = theta + IR_BEARINGS[: len(reading)]
    start_r = robot_radius_mm
    seg = np.zeros((len(reading), 2, 3), np.float32)
    seg[:, 0, 0] = x + start_r * np.cos(bearing)
    seg[:, 0, 1] = y + start_r * np.sin(bearing)
    seg[:, 1, 0] = x + (start_r + length) * np.cos(bearing)
    seg[:, 1, 1] = y + (start_r + length) * np.sin(bearing)
    seg[:, :, :2] *= MM
    seg[:, :, 2] = ROBOT_Z * 2
    return seg


def ir_level(ir: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Readings (0..1023, as many as there are IR bearings) to 0..1."""
    reading = np.asarray(ir, np.float32).reshape(-1)[: len(IR_BEARINGS)]
    return np.clip(reading, 0.0, IR_MAX) / IR_MAX


def ir_colours(ir: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """(8, 2, 3) colours for :func:`ir_segments`: pale yellow at 0 to red at 1023."""
    level = ir_level(ir)[:, None]
    rgb = IR_LOW_RGB + (IR_HIGH_RGB - IR_LOW_RGB) * level
    return np.repeat(np.rint(rgb).astype(np.uint8)[:, None, :], 2, axis=1)


def trail_segments(points_mm: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """(K, 2) successive positions to (K-1, 2, 3) segments (metres)."""
    if len(points_mm) < 2:
        return np.zeros((0, 2, 3), np.float32)
    seg = np.zeros((len(points_mm) - 1, 2, 3), np.float32)
    seg[:, 0, :2] = points_mm[:-1] * MM
    seg[:, 1, :2] = points_mm[1:] * MM
    seg[:, :, 2] = ROBOT_Z / 2
    return seg


def floor_line_segments(points_mm: tuple[tuple[float, float], ...]) -> npt.NDArray[np.float32]:
    """(S, 2, 3) segments (metres) of a polyline painted on the floor, just above it."""
    pts = np.asarray(points_mm, np.float32).reshape(-1, 2)
    if len(pts) < 2:
        return np.zeros((0, 2, 3), np.float32)
    seg = np.zeros((len(pts) - 1, 2, 3), np.float32)
    seg[:, 0, :2] = pts[:-1] * MM
    seg[:, 1, :2] = pts[1:] * MM
    seg[:, :, 2] = 0.0005
    return seg


def hex_rgb(colour: str) -> tuple[int, int, int]:
    """``#rrggbb`` as an RGB tuple (grey if it is not one)."""
    if len(colour) == 7 and colour.startswith("#"):
        try:
            return (int(colour[1:3], 16), int(colour[3:5], 16), int(colour[5:7], 16))
        except ValueError:
            pass
    return (128, 128, 128)


# A composed robot's look, by the role of the component that drew each segment: the body
# dark, IR rays red, light sensors amber, batched sensors blue, the rest grey.
LOOK_COLOURS = {
    "body": (40, 40, 40),
    "proximity": (220, 50, 50),
    "ambient": (230, 160, 0),
    "sensor": (30, 110, 230),
}


def look_segments(
    segments: list[tuple[float, float, float, float]], roles: list[str]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """(S, 2, 3) segments (metres, robot frame, just above the robot) and their colours."""
    out = np.zeros((len(segments), 2, 3), np.float32)
    if segments:
        a = np.asarray(segments, np.float32).reshape(-1, 4) * MM
        out[:, 0, :2], out[:, 1, :2] = a[:, :2], a[:, 2:]
        out[:, :, 2] = ROBOT_Z * 3
    colours = np.array([LOOK_COLOURS.get(r, (90, 90, 90)) for r in roles], np.uint8).reshape(-1, 3)
    return out, np.repeat(colours[:, None, :], 2, axis=1)
