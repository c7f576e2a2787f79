"""A race's rules, pure: a start line, laps, a finish. Fed poses, it says who has done what."""

from __future__ import annotations

from dataclasses import dataclass, field


def _side(line: tuple[float, float, float, float], x: float, y: float) -> float:
    x0, y0, x1, y1 = line
    return (x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)


def _between(line: tuple[float, float, float, float], x: float, y: float) -> bool:
    """Whether (x, y) projects onto the line segment (a crossing, not a pass beside it)."""
    x0, y0, x1, y1 = line
    dx, dy = x1 - x0, y1 - y0
    t = ((x - x0) * dx + (y - y0) * dy) / max(dx * dx + dy * dy, 1e-12)
    return 0.0 <= t <= 1.0


@dataclass
class Race:
    """Laps counted when a robot crosses the start line from its right side to its left.

    (Seen from (x0, y0) towards (x1, y1).) The first to complete ``laps`` laps
    wins; the race finishes then, and the standings are laps, then who got there first.
    """

    line: tuple[float, float, float, float]
    laps: int
    laps_done: dict[str, int] = field(default_factory=dict)
    last_side: dict[str, float] = field(default_factory=dict)
    finished_at: dict[str, float] = field(default_factory=dict)
    winner: str | None = None

    def update(self, t: float, poses: dict[str, tuple[float, float]]) -> None:
        for agent, (x, y) in poses.items():
            side = _side(self.line, x, y)
            before = self.last_side.get(agent)
            self.last_side[agent] = side
            self.laps_done.setdefault(agent, 0)
            if before is None or agent in self.finished_at:
                continue
            if before < 0 <= side and _between(self.line, x, y):
                self.laps_done[agent] += 1
                if self.laps_done[agent] >= self.laps:
                    self.finished_at[agent] = t
                    if self.winner is None:
                        self.winner = agent

    @property
    def finished(self) -> bool:
        return self.winner is not None

    def standings(self) -> list[dict[str, object]]:
        order = sorted(
            self.laps_done,
            key=lambda a: (-self.laps_done[a], self.finished_at.get(a, float("inf")), a),
        )
        return [
            {"agent": a, "laps": self.laps_done[a], "finished_at": self.finished_at.get(a)}
            for a in order
        ]
