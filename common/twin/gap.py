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
from common.twin.fit import SHIPPED_KHEPERA, RunData, open_loop_error, run_data
from common.twin.motion import Drive
from common.twin.readings import NEAR_READING, SensorError, model_readings, sensor_errors
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
        *sensor_lines(run, twin, name),
    ]


def sensor_gap(run: RunData, twin: Twin | None) -> list[SensorError]:
    """The datasheet Khepera's sensor error on ``run`` and, given one, ``twin``'s: each
    model's readings along the run's tracked path against the recorded ones."""
    khepera = SHIPPED_KHEPERA.read_text().replace('name = "khepera"', 'name = "khepera_clean"')
    robots = [("datasheet", ("khepera_clean", khepera))]
    if twin is not None:
        robots.append((twin.model(), (twin.type_name, twin.robot_file())))
    times = run.samples[:, 0]
    models = [
        (model, *model_readings(run.snapshot, run.agent, robot, run.poses, times))
        for model, robot in robots
    ]
    return sensor_errors(models, run.samples[:, 1:], run.ambient)


def sensor_lines(run: RunData, twin: Twin | None, name: str = "") -> list[str]:
    """The sensor gap as the report and the page print it."""
    errors = sensor_gap(run, twin)
    if all(e is None for e in errors[0].ir):
        return [
            f"sensor error: no IR reading of {run.agent} to compare (no sample with a "
            "camera pose near it, or no snapshot of the arena in the recording)"
        ]
    where = f" on {name}" if name else ""
    out = [
        f"sensor error{where}, median |model - recorded| (counts), IR 0..7 where the robot "
        f"or a model read {NEAR_READING:g} or more:",
        *(f"  {e.ir_line()}" for e in errors),
    ]
    if all(e is None for e in errors[0].ambient):
        out.append("  ambient: not recorded")
    else:
        out.append("  ambient 0..7, every sample (the twin's is the datasheet's: not fitted):")
        out.append(f"  {errors[0].ambient_line()}")
    return out
