"""How fast a world runs against the wall clock, said to the operator when it falls behind.

Why: a paced engine whose ticks take longer than their simulated time drifts
behind real time without a word: the robots move slowly, controllers see
late readings, and nothing says the host is the cause. The engine checks its
pace over windows of simulated progress and logs a warning when the world
runs below ``BEHIND`` of the asked speed, and a line when it keeps up again.
With ``--fast`` (no pace asked) it logs the speed it reaches, now and then.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

# Wall seconds a pace is measured over: long enough that one slow tick (a map
# load, a garbage collection) does not count as falling behind.
WINDOW_S = 10.0
# A paced world below this share of its speed is behind; it keeps up again at
# KEEPS_UP (the gap between them: one warning, not one per window, for a
# world hovering at the line).
BEHIND = 0.9
KEEPS_UP = 0.97
# With --fast: how often the reached speed is logged.
FAST_REPORT_S = 60.0


@dataclass(frozen=True)
class PaceReport:
    """What a window showed: ``factor`` simulated seconds per wall second."""

    level: str  # "warning" (fell behind) or "info" (keeps up again; a --fast report)
    factor: float
    text: str


class PaceWatch:
    """Feed it the world's simulated time once a tick; it says when the pace changes.

    ``speed`` is the asked speed (times real time), None for ``--fast``.
    ``describe`` names the world and its size for the messages (called only
    when one is made).
    """

    def __init__(
        self,
        speed: float | None,
        describe: Callable[[], str],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.speed = speed
        self.describe = describe
        self.clock = clock
        self.behind = False
        self.factor: float | None = None  # the last window's, once one has ended
        self._window = FAST_REPORT_S if speed is None else WINDOW_S
        self._wall0: float | None = None
        self._sim0 = 0.0

    def restart(self) -> None:
        """Forget the window (a new world: its simulated time starts again)."""
        self._wall0 = None

    def tick(self, sim_time: float) -> PaceReport | None:
        now = self.clock()
        if self._wall0 is None or sim_time < self._sim0:
            self._wall0, self._sim0 = now, sim_time
            return None
        wall = now - self._wall0
        if wall < self._window:
            return None
        factor = (sim_time - self._sim0) / wall
        self._wall0, self._sim0 = now, sim_time
        self.factor = factor
        if self.speed is None:
            return PaceReport(
                "info",
                factor,
                f"{self.describe()} runs at {factor:.2f}x real time (--fast, "
                f"over the last {wall:.0f} s)",
            )
        if not self.behind and factor < BEHIND * self.speed:
            self.behind = True
            return PaceReport(
                "warning",
                factor,
                f"{self.describe()} runs at {factor:.2f}x real time over the last "
                f"{wall:.0f} s, asked {self.speed:g}x: its ticks take longer than the "
                "time they simulate on this host, so robots move slowly and "
                "controllers get late readings. Fewer robots, the discs drive "
                "(the default, if it was started with another), --threads, or a host of its own: "
                "docs/OPERATIONS.md, 'When a world falls behind'",
            )
        if self.behind and factor >= KEEPS_UP * self.speed:
            self.behind = False
            return PaceReport(
                "info",
                factor,
                f"{self.describe()} keeps up again: {factor:.2f}x real time over the "
                f"last {wall:.0f} s (asked {self.speed:g}x)",
            )
        return None
