"""The twin's fit against a ground truth it never reads: the emulated body's own parameters.

Each test drives the calibration dance on the emulated Khepera's body (the simulator's
Khepera with a body file's true parameters) on a simulated clock, records it as a real
run is recorded, and fits (services/bridge/rehearse.py, common/twin/fit.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from common.recording import read_recording
from common.twin.fit import TwinError, calibrate, open_loop_error, run_data
from common.twin.motion import Drive
from services.bridge.body_truth import BodyTruth, BodyTruthError
from services.bridge.rehearse import rehearse, write_rehearsal
from services.commands import calibrate as calibrate_cli

HIDDEN = BodyTruth(
    wheel_scale=(0.96, 1.03),
    wheel_base_mm=50.5,
    latency_s=0.08,
    ir_gain=(1.1, 0.85, 1.0, 1.2, 0.9, 1.0, 0.8, 1.05),
    ir_noise_counts=4.0,
    seed=11,
)


def estimates(name: str, twin) -> dict[str, float]:  # type: ignore[no-untyped-def]
    return {e.name: e.value for e in (*twin.drive, *twin.proximity) if not e.refused}


def test_the_fit_recovers_a_hidden_robot_and_its_twin_strays_far_less() -> None:
    rec = rehearse(HIDDEN, seed=4)
    twin = calibrate("k1", [("dance", rec)])
    got = estimates("k1", twin)
    assert got["scale_left"] == pytest.approx(0.96, abs=0.005)
    assert got["scale_right"] == pytest.approx(1.03, abs=0.005)
    assert got["wheel_base_mm"] == pytest.approx(50.5, abs=0.5)
    assert got["latency_s"] == pytest.approx(0.08, abs=0.01)
    for i, gain in enumerate(HIDDEN.ir_gain):
        assert got[f"ir{i}_gain"] == pytest.approx(gain, abs=0.03), i
    run = run_data(rec, "dance")
    datasheet, fitted = (
        open_loop_error(Drive(), run, 5.0),
        open_loop_error(twin.fitted_drive(), run, 5.0),
    )
    assert fitted < datasheet / 5, (fitted, datasheet)
    assert all(e.runs == ["dance"] and e.sigma is not None for e in twin.drive)


def test_a_robot_that_only_drove_straight_says_nothing_of_its_wheel_base() -> None:
    straight = rehearse(HIDDEN, seed=4, seconds=6.0)  # only the drive toward the wall
    twin = calibrate("k1", [("straight", straight)])
    said = {e.name: e for e in twin.drive}
    # It turned a little (its wheels slip unevenly), never with its wheels commanded apart.
    assert "with its wheels commanded apart for 0.0 s" in said["wheel_base_mm"].refused
    assert said["wheel_base_mm"].value == 53.0  # kept at the datasheet's
    assert "the latency needs 4 changes" in said["latency_s"].refused
    assert not said["scale_left"].refused and not said["scale_right"].refused


def test_a_recording_without_the_camera_is_refused_in_words() -> None:
    rec = rehearse(HIDDEN, seed=4, seconds=3.0)
    rec.tracked.clear()
    with pytest.raises(TwinError, match=r"has 0 camera pose.*watched by `wart camera`"):
        calibrate("k1", [("blind", rec)])


def test_wart_calibrate_prints_the_twin_and_writes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_rehearsal(rehearse(HIDDEN, seed=4), tmp_path / "dance.mcap")
    assert read_recording(path).info is not None
    out = tmp_path / "k1.json"
    assert calibrate_cli.main(["k1", "--recordings", str(path), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "k1's twin from 1 run(s)" in said and "wheel_base_mm: 50." in said
    assert '"format": "wart-twin"' in out.read_text()
    assert calibrate_cli.main(["k9", "--recordings", str(path)]) == 1
    assert "dance is a run of k1, not k9" in capsys.readouterr().err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    assert calibrate_cli.main(["k1", "--recordings", str(junk)]) == 1


def test_a_body_file_is_checked_field_by_field(tmp_path: Path) -> None:
    bad = tmp_path / "body.toml"
    bad.write_text('wheel_scale = [0.9]\nlatency_s = 2\ncolour = "red"\n')
    with pytest.raises(BodyTruthError) as info:
        BodyTruth.read(bad)
    said = str(info.value)
    assert "wheel_scale: a list of 2 numbers" in said
    assert "latency_s: a number from 0 to 0.5, not 2" in said
    assert "colour: unknown field" in said
