"""An engine that cannot keep its pace says so (services/engine/pace.py).

What an operator relies on: a world that runs below the asked speed for a
window is reported once, with its speed and what to do; once it keeps up
again that is said too; a world hovering near the line is not reported
window after window; a world restarted (a map loaded) starts a new window;
with --fast the reached speed is logged now and then.
"""

from __future__ import annotations

from services.engine.pace import FAST_REPORT_S, WINDOW_S, PaceReport, PaceWatch


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _run(
    watch: PaceWatch, clock: Clock, factor: float, wall_s: float, sim: float
) -> tuple[list[PaceReport], float]:
    """Ticks of 20 ms of simulated time at ``factor`` for ``wall_s``: (reports, sim time)."""
    reports = []
    step = 0.02 / factor
    end = clock.now + wall_s
    while clock.now < end:
        clock.now += step
        sim += 0.02
        report = watch.tick(sim)
        if report is not None:
            reports.append(report)
    return reports, sim


def test_a_world_falling_behind_is_reported_once_and_its_return_too() -> None:
    clock = Clock()
    watch = PaceWatch(1.0, lambda: "world arena (10000 robots, discs drive)", clock)
    reports, sim = _run(watch, clock, 1.0, 3 * WINDOW_S, 0.0)
    assert reports == [] and not watch.behind
    reports, sim = _run(watch, clock, 0.6, 4 * WINDOW_S, sim)
    assert [r.level for r in reports] == ["warning"], reports
    warning = reports[0]
    assert 0.55 < warning.factor < 0.65
    assert "world arena (10000 robots, discs drive) runs at 0.6" in warning.text
    assert "asked 1x" in warning.text and "OPERATIONS.md" in warning.text
    assert watch.behind
    reports, sim = _run(watch, clock, 1.0, 3 * WINDOW_S, sim)
    assert [r.level for r in reports] == ["info"], reports
    assert "keeps up again" in reports[0].text and not watch.behind


def test_a_world_hovering_at_the_line_is_not_reported_window_after_window() -> None:
    clock = Clock()
    watch = PaceWatch(2.0, lambda: "world w", clock)
    reports, sim = _run(watch, clock, 1.7, 2 * WINDOW_S, 0.0)  # 0.85 of 2x: behind
    assert [r.level for r in reports] == ["warning"]
    # Between BEHIND and KEEPS_UP: neither a new warning nor "keeps up".
    reports, _ = _run(watch, clock, 1.88, 5 * WINDOW_S, sim)
    assert reports == [] and watch.behind


def test_a_world_that_starts_again_starts_a_new_window() -> None:
    clock = Clock()
    watch = PaceWatch(1.0, lambda: "world w", clock)
    _run(watch, clock, 1.0, WINDOW_S / 2, 50.0)
    # A map loaded: simulated time starts again at 0, and the half window
    # before it does not count against the new world.
    clock.now += WINDOW_S  # the load took long
    reports, _ = _run(watch, clock, 1.0, WINDOW_S * 1.5, 0.0)
    assert reports == [] and not watch.behind


def test_fast_runs_report_the_speed_reached() -> None:
    clock = Clock()
    watch = PaceWatch(None, lambda: "world w", clock)
    reports, _ = _run(watch, clock, 1.9, 2.5 * FAST_REPORT_S, 0.0)
    assert len(reports) == 2 and all(r.level == "info" for r in reports)
    assert "1.90x real time (--fast" in reports[0].text
