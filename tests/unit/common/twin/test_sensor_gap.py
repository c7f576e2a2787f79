"""The sensor gap: what the datasheet Khepera and a twin read along a real run, against
what the robot read, sensor by sensor, in ``wart report`` and ``wart calibrate``.

The run is a rehearsal of the calibration dance on the emulated Khepera's body with
IR gains the fitter never reads (services/bridge/rehearse.py), written and read back
as an MCAP file as a real run's is; the models' readings come from the simulator's
own sensor model in the run's arena, rebuilt from the recording's snapshot.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.messages import WorldSnapshot
from common.messages.world import ItemInfo, ShapeInfo
from common.twin.fit import SHIPPED_KHEPERA
from common.twin.readings import SENSORS, model_readings
from services.bridge.body_truth import BodyTruth
from services.bridge.rehearse import rehearse, write_rehearsal
from services.commands import calibrate as calibrate_cli
from services.commands import report as report_cli

# Sensor 3 reads 1.3 times the datasheet's curve, sensor 6 0.7 times; the others 1.
HIDDEN = BodyTruth(
    wheel_scale=(0.97, 1.02),
    wheel_base_mm=51.0,
    latency_s=0.05,
    ir_gain=(1.0, 1.0, 1.0, 1.3, 1.0, 1.0, 0.7, 1.0),
    ir_noise_counts=3.0,
    seed=5,
)


def figures(line: str) -> list[float | None]:
    """The eight figures after a model's name: "datasheet: 3 / - / 40 ..."."""
    values = line.rsplit(": ", 1)[1].split(" / ")
    return [None if v == "-" else float(v) for v in values]


def test_the_report_gives_each_models_sensor_error_on_a_real_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = write_rehearsal(rehearse(HIDDEN, seed=3), tmp_path / "dance.mcap")
    twin = tmp_path / "k1.json"
    assert calibrate_cli.main(["k1", "--recordings", str(run), "--out", str(twin)]) == 0
    fitted = capsys.readouterr().out
    assert "sensor error on dance, median |model - recorded| (counts)" in fitted, fitted
    assert report_cli.main([str(run), "--twin", str(twin)]) == 0
    said = capsys.readouterr().out
    lines = said.splitlines()
    at = lines.index(next(x for x in lines if x.startswith("sensor error on dance")))
    datasheet, by_twin = figures(lines[at + 1]), figures(lines[at + 2])
    assert lines[at + 1].strip().startswith("datasheet:"), said
    assert "k1's twin fitted" in lines[at + 2], said
    # The dance turns every sensor to the wall: each has readings to compare.
    assert all(e is not None for e in datasheet + by_twin), said
    # Where the robot's sensor is not the datasheet's, the datasheet model is off by
    # far more than on the sensors that are; the twin, which took each sensor's gain,
    # is not.
    plain = [datasheet[i] for i in (0, 1, 2, 4, 5, 7)]
    for i in (3, 6):
        assert datasheet[i] > 2 * max(plain), (i, said)  # type: ignore[type-var]
        assert by_twin[i] < datasheet[i] / 2, (i, said)  # type: ignore[operator]
    # The ambient sensors were recorded: the datasheet's model beside them.
    assert "ambient 0..7, every sample" in said, said


def test_the_models_readings_are_in_the_runs_arena_obstacles_included() -> None:
    box = ItemInfo(
        id="box", category="obstacle", kind="box", colour="#888888", x=600.0, y=500.0,
        heading=0.0, shape=ShapeInfo(kind="polygon", points=[(-50, -50), (50, -50), (50, 50),
                                                             (-50, 50)]),
    )  # fmt: skip
    arena = WorldSnapshot(
        world="real", tick=0, sim_time=0.0, layout=0, tick_s=0.01, seed=0, width=1000.0,
        height=1000.0, items=[box], lights=[], agents=[], rows=[], kind="real",
    )  # fmt: skip
    khepera = ("khepera_clean", SHIPPED_KHEPERA.read_text().replace('"khepera"', '"khepera_clean"'))
    # The robot 2.5 mm short of the box's face, facing it; then the camera loses it. The
    # first pose the camera gave puts it inside the box (a bad pose): it is placed by the next.
    poses = np.array([[0.0, 560.0, 500.0, 0.0], [0.1, 520.0, 500.0, 0.0], [0.3, 520.0, 500.0, 0.0]])
    times = np.array([0.2, 2.0])
    ir, ambient = model_readings(arena, "k1", khepera, poses, times)
    assert ir[0, 2] > 300 and ir[0, 3] > 300, ir  # the front pair sees the box
    assert ir[0, 6] == 0 and ir[0, 7] == 0, ir  # nothing behind
    assert np.isnan(ir[1]).all() and np.isnan(ambient[1]).all()  # no pose at 2 s
    empty = arena.__class__(**{**{f: getattr(arena, f) for f in arena.__struct_fields__},
                               "items": []})  # fmt: skip
    alone, _ = model_readings(empty, "k1", khepera, poses, times)
    assert alone[0, :SENSORS].max() == 0, alone
    assert not math.isnan(ambient[0, 0])
