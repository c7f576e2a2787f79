"""The floor layer of a world: a background shade and lines painted on it (line following).

Optional in a map (docs/MAPS.md, ``floor``): a world without one has a plain
white floor. A floor sensor (common/robots/sensors.py) reads the shade under a
point of the robot: 0 black .. 255 white, the reflectance a downward IR sensor
sees. Lines are thick segments; where lines cross, the later one is on top.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WHITE = 255.0


def shade(colour: str) -> float:
    """A ``#rrggbb`` colour's grey level (ITU-R BT.601 luma), 0..255."""
    r, g, b = (int(colour[i : i + 2], 16) for i in (1, 3, 5))
    return 0.299 * r + 0.587 * g + 0.114 * b


@dataclass(frozen=True)
class FloorLine:
    """A painted polyline: its points (mm), width (mm) and colour."""

    points: tuple[tuple[float, float], ...]
    width_mm: float
    colour: str


@dataclass(frozen=True)
class FloorLayer:
    colour: str = "#ffffff"
    lines: tuple[FloorLine, ...] = ()

    def segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(S, 4) segments, (S,) half widths, (S,) shades, in painting order."""
        segs, half, grey = [], [], []
        for line in self.lines:
            g = shade(line.colour)
            for a, b in zip(line.points, line.points[1:], strict=False):
                segs.append((*a, *b))
                half.append(line.width_mm / 2)
                grey.append(g)
        return (
            np.array(segs, dtype=np.float64).reshape(-1, 4),
            np.array(half, dtype=np.float64),
            np.array(grey, dtype=np.float64),
        )

    def sample(self, points: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """The shade under each of (M, 2) points, 0..255 (vectorised, in chunks of points)."""
        out = np.full(len(points), shade(self.colour))
        segs, half, grey = self.segments()
        if not len(segs) or not len(points):
            return out
        a, d = segs[:, :2], segs[:, 2:] - segs[:, :2]
        dd = np.maximum(np.sum(d * d, axis=1), 1e-12)
        for lo in range(0, len(points), chunk):
            p = points[lo : lo + chunk, None, :]  # (m, 1, 2) against (S, 2)
            t = np.clip(np.sum((p - a) * d, axis=2) / dd, 0.0, 1.0)
            gap = p - (a + t[..., None] * d)
            inside = np.sum(gap * gap, axis=2) <= half * half  # (m, S)
            # the last segment painted over a point is the one seen
            last = len(segs) - 1 - np.argmax(inside[:, ::-1], axis=1)
            hit = inside.any(axis=1)
            out[lo : lo + chunk][hit] = grey[last[hit]]
        return out
