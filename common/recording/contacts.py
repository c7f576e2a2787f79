"""What a recorded robot touched, from the recorded poses alone (no physics needed).

A robot's footprint is its disc and, when the world says its gripper's tongs
collide with robots and walls (``AgentInfo.tongs``, the joints drive), the two
tongs in front of it: the dry run counts a tong that touches a robot or a wall
as a collision, so the recording counts it too.

Touching is within :data:`CONTACT_MM` of the other thing's outline. Each
stretch of touching one kind of thing (the arena's ``wall``, an ``obstacle``,
another ``robot``) is one collision with that kind, as the dry run counts a new
contact; a robot pushed along stays one collision until the two part by more
than :data:`PART_MM` (frames every 40 ms, a push jitters by a few mm).
"""

from __future__ import annotations

import math

import numpy as np

from common.messages import AgentInfo, ItemInfo, WorldSnapshot
from common.recording.reader import Recording

CONTACT_MM = 2.0  # touching: the pymunk contact slop and float32 poses are below this
PART_MM = 6.0  # apart again: a gap this wide ends a stretch of touching
KINDS = ("wall", "obstacle", "robot")
_TONG_SAMPLES = 5  # points along a tong tested against walls and obstacles


def radius_of(snap: WorldSnapshot | None, agent: str) -> float:
    info = agent_info(snap, agent)
    return info.radius if info is not None else 35.0  # a Khepera's


def agent_info(snap: WorldSnapshot | None, agent: str) -> AgentInfo | None:
    if snap is not None:
        for a in snap.agents:
            if a.id == agent:
                return a
    return None


def outline(item: ItemInfo) -> np.ndarray | None:
    """A polygon item's corners in the world (mm); None for a circle."""
    if item.shape.kind != "polygon" or not item.shape.points:
        return None
    pts = np.array(item.shape.points, dtype=float)
    c, s = math.cos(item.heading), math.sin(item.heading)
    rot = np.array([[c, -s], [s, c]])
    return pts @ rot.T + np.array([item.x, item.y])


def segment_distance(px: np.ndarray, py: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    length2 = float(ab @ ab) or 1e-12
    t = np.clip(((px - a[0]) * ab[0] + (py - a[1]) * ab[1]) / length2, 0.0, 1.0)
    return np.hypot(px - (a[0] + t * ab[0]), py - (a[1] + t * ab[1]))


def _inside(px: np.ndarray, py: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule, vectorised over points."""
    inside = np.zeros(px.shape, bool)
    n = len(poly)
    for i in range(n):
        (x1, y1), (x2, y2) = poly[i], poly[(i + 1) % n]
        crosses = (y1 > py) != (y2 > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xcross = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (px < xcross)
    return inside


def clearance(item: ItemInfo, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Distance from each point to the item's outline (negative inside)."""
    poly = outline(item)
    if poly is None:
        return np.hypot(px - item.x, py - item.y) - item.shape.radius
    d = np.min(
        [segment_distance(px, py, poly[i], poly[(i + 1) % len(poly)]) for i in range(len(poly))],
        axis=0,
    )
    return np.where(_inside(px, py, poly), -d, d)


def _map_gaps(snap: WorldSnapshot, px: np.ndarray, py: np.ndarray) -> dict[str, np.ndarray]:
    """Each point's gap to the arena's edge and to the nearest obstacle (mm)."""
    edge = np.minimum.reduce([px, py, snap.width - px, snap.height - py])
    obstacle = np.full(px.shape, np.inf)
    for item in snap.items:
        if item.category == "obstacle":
            obstacle = np.minimum(obstacle, clearance(item, px, py))
    return {"wall": edge, "obstacle": obstacle}


def _tong_points(
    info: AgentInfo | None, xs: np.ndarray, ys: np.ndarray, hs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """Points along each tong, in the world: (frames, points) x and y, and the tongs' half width."""
    if info is None or not info.tongs:
        return np.empty((len(xs), 0)), np.empty((len(xs), 0)), 0.0
    local = [(x, y) for x0, x1, y, _ in info.tongs for x in np.linspace(x0, x1, _TONG_SAMPLES)]
    lx = np.array([p[0] for p in local])
    ly = np.array([p[1] for p in local])
    c, s = np.cos(hs)[:, None], np.sin(hs)[:, None]
    return xs[:, None] + c * lx - s * ly, ys[:, None] + s * lx + c * ly, info.tongs[0][3]


def map_contact(
    snap: WorldSnapshot,
    radius: float,
    xs: np.ndarray,
    ys: np.ndarray,
    hs: np.ndarray | None = None,
    info: AgentInfo | None = None,
) -> dict[str, np.ndarray]:
    """Per frame and kind of map thing: the footprint's gap to it (mm)."""
    gaps = {k: g - radius for k, g in _map_gaps(snap, xs, ys).items()}
    if hs is not None:
        tx, ty, half = _tong_points(info, xs, ys, hs)
        if tx.shape[1]:
            tong = _map_gaps(snap, tx.ravel(), ty.ravel())
            for kind, g in tong.items():
                gaps[kind] = np.minimum(gaps[kind], g.reshape(tx.shape).min(axis=1) - half)
    return gaps


def robot_gaps(rec: Recording, agent: str, snap: WorldSnapshot | None) -> np.ndarray:
    """Per frame that shows ``agent``: the gap (mm) between its footprint and the nearest other
    robot's (inf when it is alone). Tongs count both ways: mine on their disc, theirs on mine."""
    infos = {a.id: a for a in snap.agents} if snap is not None else {}
    me = infos.get(agent)
    radius = me.radius if me is not None else 35.0
    gaps: list[float] = []
    for stamped in rec.frames:
        f = stamped.record
        n = min(f.agents, len(f.rows), len(f.x), len(f.y), len(f.heading))
        try:
            row = f.rows.index(agent)
        except ValueError:
            continue
        if row >= n or n < 2:
            gaps.append(math.inf)
            continue
        ox = np.asarray(f.x[:n], float)
        oy = np.asarray(f.y[:n], float)
        oh = np.asarray(f.heading[:n], float)
        others = np.arange(n) != row
        radii = np.array([infos[r].radius if r in infos else 35.0 for r in f.rows[:n]])
        x, y, h = ox[row], oy[row], oh[row]
        gap = np.hypot(ox - x, oy - y) - radius - radii
        gap = gap[others]
        # My tongs on their discs.
        tx, ty, half = _tong_points(me, np.array([x]), np.array([y]), np.array([h]))
        if tx.shape[1]:
            d = np.hypot(tx[0][:, None] - ox[others], ty[0][:, None] - oy[others]).min(axis=0)
            gap = np.minimum(gap, d - half - radii[others])
        # Their tongs on my disc.
        for j, i in enumerate(np.flatnonzero(others)):
            info = infos.get(f.rows[i])
            if info is None or not info.tongs:
                continue
            px, py, theirs = _tong_points(info, ox[i : i + 1], oy[i : i + 1], oh[i : i + 1])
            gap[j] = min(gap[j], float(np.hypot(px[0] - x, py[0] - y).min()) - theirs - radius)
        gaps.append(float(gap.min()))
    return np.array(gaps)


def stretches(gap: np.ndarray) -> np.ndarray:
    """Which frames are in a stretch of touching: it starts within CONTACT_MM, ends past PART_MM."""
    touching = np.zeros(gap.shape, bool)
    on = False
    for i, g in enumerate(gap):
        on = g <= CONTACT_MM if not on else g <= PART_MM
        touching[i] = on
    return touching


def count(touching: np.ndarray) -> int:
    if not len(touching):
        return 0
    return int(np.count_nonzero(touching[1:] & ~touching[:-1]) + int(touching[0]))


def count_collisions(gaps: dict[str, np.ndarray], ts: np.ndarray) -> tuple[dict[str, int], float]:
    """Collisions with each kind of thing, and the seconds in contact with anything."""
    by_kind: dict[str, int] = {}
    any_touch = np.zeros(ts.shape, bool)
    for kind in KINDS:
        if kind not in gaps or not len(gaps[kind]):
            continue
        touching = stretches(gaps[kind])
        if n := count(touching):
            by_kind[kind] = n
        any_touch |= touching
    dt = np.diff(ts, prepend=ts[0]) if len(ts) else ts
    return by_kind, float(dt[any_touch].sum()) if len(ts) else 0.0
