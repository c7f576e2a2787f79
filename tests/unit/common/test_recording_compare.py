"""Sim beside real: two synthetic recordings with planted differences compare to those numbers."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import pytest

from common.recording import RecordingError, RecordingWriter, read_recording
from common.recording import schema as s
from common.recording.compare import CompareError, compare
from common.sim2d import maps
from common.world import packing
from services.commands import report

REPO = Path(__file__).resolve().parents[3]
SECONDS = 2.0
DT = 0.02
OFFSET = (30.0, 40.0)  # planted: B ends this far from A (50 mm), having started where A did
IR_SHIFT = 10  # planted: B's IR reads this much more than A's, every sensor
AMBIENT_SHIFT = -5


def _write(
    path: Path,
    start: float,
    *,
    offset: tuple[float, float] = (0.0, 0.0),
    ir: int = 0,
    ambient: int = 0,
    robot_type: str = "khepera",
    frames: bool = True,
) -> Path:
    """A straight run at 80 mm/s from (300, 500), drifting linearly to ``offset`` at the end."""
    snap = packing.snapshot(maps.load_map(REPO / "maps" / "empty.json", name="w1", seed=1))
    agent = snap.agents[0].id
    if robot_type != "khepera":
        snap = msgspec.structs.replace(
            snap, agents=[msgspec.structs.replace(a, type=robot_type) for a in snap.agents]
        )
    info = s.RunInfo(
        ctx="arena",
        world="w1",
        agent=agent,
        user="alice",
        request_id=f"{agent}-{int(start)}-abc",
        mode="deploy",
        filename="ctl.py",
        start=start,
        planned_end=start + SECONDS,
    )
    writer = RecordingWriter(path, info)
    writer.write(s.SNAPSHOT, snap, start)
    steps = int(SECONDS / DT)
    for i in range(steps + 1 if frames else 0):
        t = i * DT
        drift = t / SECONDS
        x = 300.0 + 80.0 * t + offset[0] * drift
        y = 500.0 + offset[1] * drift
        frame = s.FrameRecord(
            tick=i,
            sim_time=1000.0 + t,  # another clock than the slot's: must not matter
            layout=0,
            agents=1,
            rows=[agent],
            x=[x],
            y=[y],
            heading=[0.0],
            fingers=[0],
        )
        writer.write(s.FRAME, frame, start + t)
        # A sensor wave, so aligning on the wrong clock would not give the planted shift.
        wave = int(100 + 50 * math.sin(2 * math.pi * t))
        sample = s.SampleRecord(
            agent=agent,
            tick=i,
            sim_time=1000.0 + t,
            proximity=[wave + k + ir for k in range(8)],
            ambient=[400 + k + ambient for k in range(8)],
            counters=(i, i),
            speeds=(10, 10),
            leds=[0, 0],
        )
        writer.write(s.sensors_topic(agent), sample, start + t)
    writer.finish(s.RunEnd(status="finished", reason="slot over", at=start + SECONDS))
    return path


def test_the_planted_offset_is_the_final_pose_error(tmp_path: Path) -> None:
    sim = read_recording(_write(tmp_path / "sim.mcap", 1_000_000.0))
    # The real run's slot starts 100 s later: the runs are aligned on their slots' starts.
    real = read_recording(
        _write(
            tmp_path / "real.mcap",
            1_000_100.0,
            offset=OFFSET,
            ir=IR_SHIFT,
            ambient=AMBIENT_SHIFT,
        )
    )
    cmp = compare(sim, real)
    assert cmp.a.label == "sim" and cmp.b.label == "real"
    assert cmp.start_offset_mm == 0.0
    assert cmp.final_pose_error_mm == pytest.approx(math.hypot(*OFFSET), abs=0.1)
    assert cmp.final_heading_error_rad == 0.0
    expected_ratio = math.hypot(80 * SECONDS + OFFSET[0], OFFSET[1]) / (80 * SECONDS)
    assert cmp.path_length_ratio == pytest.approx(expected_ratio, abs=0.01)
    assert cmp.a.collisions == 0 and cmp.b.collisions == 0
    assert cmp.aligned_samples > 90
    assert cmp.ir_mean_diff == pytest.approx([IR_SHIFT] * 8, abs=0.01)
    assert cmp.ir_mean_abs_diff == pytest.approx([IR_SHIFT] * 8, abs=0.01)
    assert cmp.ambient_mean_diff == pytest.approx([AMBIENT_SHIFT] * 8, abs=0.01)
    assert cmp.warnings == []


def test_the_command_prints_every_number_and_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sim = _write(tmp_path / "sim.mcap", 1_000_000.0)
    real = _write(tmp_path / "real.mcap", 1_000_100.0, offset=OFFSET, ir=IR_SHIFT)
    assert report.main([str(sim), "--against", str(real)]) == 0
    text = capsys.readouterr().out
    for name in (
        "final pose error:   50.0 mm",
        "path length ratio:",
        "collisions:",
        "IR mean difference:        +10.0",
        "ambient mean difference:",
    ):
        assert name in text, text
    assert report.main([str(sim), "--against", str(real), "--json"]) == 0
    data = msgspec.json.decode(capsys.readouterr().out)
    assert data["final_pose_error_mm"] == pytest.approx(50.0, abs=0.1)


def test_a_corrupt_an_empty_and_a_foreign_recording_are_clear_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sim = _write(tmp_path / "sim.mcap", 1_000_000.0)
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + b"\x00garbage" * 50)
    assert report.main([str(sim), "--against", str(corrupt)]) == 1
    err = capsys.readouterr().err
    assert "error:" in err and "corrupt.mcap" in err and "Traceback" not in err
    empty = read_recording(_write(tmp_path / "empty.mcap", 1_000_000.0, frames=False))
    with pytest.raises(CompareError, match=r"empty\.mcap\) is empty: no frames of robot k1"):
        compare(read_recording(sim), empty)
    other = read_recording(_write(tmp_path / "epuck.mcap", 1_000_000.0, robot_type="epuck"))
    with pytest.raises(CompareError, match="is a epuck, not a khepera"):
        compare(read_recording(sim), other)
    assert issubclass(CompareError, RecordingError)  # the command reports both alike


def test_a_run_cut_short_is_compared_as_far_as_it_goes(tmp_path: Path) -> None:
    sim = read_recording(_write(tmp_path / "sim.mcap", 1_000_000.0))
    data = _write(tmp_path / "whole.mcap", 1_000_100.0).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    short = read_recording(cut)
    if not short.frames:
        pytest.skip("the cut left no frame (chunking changed)")
    cmp = compare(sim, short)
    assert any("cut short" in w for w in cmp.warnings), cmp.warnings
    assert math.isfinite(cmp.final_pose_error_mm)
