"""The gap between a model and a real run: each model run open-loop on the run's commands.

From every camera pose of the run, a motion model (the datasheet's, a twin's) is
driven by the recorded commands for 1, 5 and 10 s and compared with where the
camera saw the robot then; the median distance is the model's gap at that
horizon. ``wart calibrate`` prints it for the runs it fitted, ``wart report
--against`` for any real run, the datasheet model and the twin side by side.
"""

from __future__ import annotations

from dataclasses import dataclass

from common.recording.reader import Recording
from common.twin.fit import RunData, open_loop_error, run_data
from common.twin.motion import Drive
from common.twin.twinfile import Twin

HORIZONS_S = (1.0, 5.0, 10.0)


@dataclass(frozen=True)
class Gap:
    """One model's median open-loop error (mm) at each horizon; None: no run that long."""

    model: str
    errors: tuple[float | None, ...]

    def line(self) -> str:
        figures = " / ".join("-" if e is None else f"{e:.1f}" for e in self.errors)
        return f"{self.model}: {figures}"


def gap(name: str, drive: Drive, runs: list[RunData]) -> Gap:
    """``drive``'s gap on ``runs`` (of several runs, the worst run's at each horizon)."""
    out: list[float | None] = []
    for horizon in HORIZONS_S:
        known = [e for e in (open_loop_error(drive, r, horizon) for r in runs) if e == e]
        out.append(max(known) if known else None)  # NaN (above): a run shorter than that
    return Gap(name, tuple(out))


def heading() -> str:
    return f"open-loop error after {' / '.join(f'{h:g}' for h in HORIZONS_S)} s (median mm)"


def side_by_side(real: Recording, name: str, twin: Twin) -> list[str]:
    """The datasheet model's and ``twin``'s gap on a real run, as the report prints it
    (TwinError: the run cannot show it; ValueError: the twin is another robot's)."""
    run = run_data(real, name)
    if twin.robot != run.agent:
        raise ValueError(f"the twin is {twin.robot}'s; {name} is a run of {run.agent}")
    return [
        f"gap on {name} ({run.agent}), {heading()}:",
        f"  {gap('datasheet', Drive(), [run]).line()}",
        f"  {gap(twin.model(), twin.drive, [run]).line()}",
    ]
