"""What ``wart camera --source`` accepts, and what a user reads when a source fails."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pytest

from common.tracking.truth import ArenaTruth, TruthError, now_truth, read_truth, write_truth
from services.camera.arguments import source_arguments
from services.camera.sources import SourceError, check_spec, describe_spec, open_source


@pytest.mark.parametrize(
    ("spec", "said"),
    [
        ("/dev/video0", "video device /dev/video0"),
        ("2", "video device 2"),
        ("rtsp://ana:secret@cam.lab/stream", "stream rtsp://***@cam.lab/stream"),
        ("arena.mp4", "video file arena.mp4"),
        ("synthetic:/tmp/t.json", "synthetic camera over /tmp/t.json"),
    ],
)
def test_sources_are_named_in_words_without_passwords(spec: str, said: str) -> None:
    assert describe_spec(spec) == said


@pytest.mark.parametrize("spec", ["", "synthetic:", "a\nb", "x" * 2000])
def test_a_bad_source_is_refused(spec: str) -> None:
    with pytest.raises(ValueError, match=r"source|synthetic"):
        check_spec(spec)


def test_a_missing_video_file_says_so(tmp_path: Path) -> None:
    source = open_source(str(tmp_path / "gone.mp4"))
    with pytest.raises(SourceError, match="no video file at"):
        source.open()


def test_a_synthetic_camera_without_its_truth_says_what_to_run(tmp_path: Path) -> None:
    source = open_source(f"synthetic:{tmp_path / 'truth.json'}")
    with pytest.raises(SourceError, match="is the emulator running with --truth"):
        source.open()


def test_a_stale_truth_is_an_offline_camera(tmp_path: Path) -> None:
    path = tmp_path / "truth.json"
    truth = now_truth(1000, 1000, {"k1": (500.0, 500.0, 0.0)})
    write_truth(path, truth.__class__(1000, 1000, truth.robots, time.time() - 10))
    with pytest.raises(SourceError, match="stopped writing"):
        open_source(f"synthetic:{path}").read()


def test_a_synthetic_frame_is_stamped_when_its_poses_were_true_not_when_rendered(
    tmp_path: Path,
) -> None:
    # A loaded host reads a truth file written 0.1 to 1.5 s before; stamped with the time
    # it was rendered, the frame paired the robot's old place with its odometry of now.
    path = tmp_path / "truth.json"
    written = time.time() - 0.7
    write_truth(path, ArenaTruth(1000, 800, {"k1": (500.0, 400.0, 0.0)}, written))
    source = open_source(f"synthetic:{path}")
    source.read()
    assert source.captured_at == written


def test_a_fresh_truth_renders_a_frame(tmp_path: Path) -> None:
    path = tmp_path / "truth.json"
    write_truth(path, now_truth(1000, 800, {"k1": (500.0, 400.0, 0.0)}))
    frame = open_source(f"synthetic:{path}").read()
    assert frame.shape == (480, 640, 3)


@pytest.mark.parametrize(
    "document",
    [
        {"format": "wart-map"},
        {
            "format": "wart-arena-truth",
            "version": 1,
            "width_mm": 1000,
            "height_mm": 1000,
            "at": 0,
            "robots": {"k 1": [0, 0, 0]},
        },
        {
            "format": "wart-arena-truth",
            "version": 1,
            "width_mm": -1,
            "height_mm": 1000,
            "at": 0,
            "robots": {},
        },
        {
            "format": "wart-arena-truth",
            "version": 1,
            "width_mm": 1000,
            "height_mm": 1000,
            "at": 0,
            "robots": {"k1": [0, "nan", 0]},
        },
    ],
)
def test_a_wrong_truth_file_is_refused(tmp_path: Path, document: dict[str, object]) -> None:
    path = tmp_path / "truth.json"
    path.write_text(json.dumps(document))
    with pytest.raises(TruthError, match=str(path)):
        read_truth(path)


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--reference-grid", "3"], "COLUMNSxROWS, e.g. 3x2"),
        (["--reference-grid", "9x2"], "2 to 5 columns by 2 to 5 rows"),
        (["--synthetic-over", "0,0,1100"], "X0,Y0,X1,Y1 in mm"),
        (["--synthetic-over", "500,0,100,1000"], "at least 100 mm each way"),
        (["--synthetic-over", "0,0,nan,1000"], "finite mm"),
    ],
)
def test_a_bad_grid_or_view_is_refused_in_words(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser()
    source_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--world", "w", "--source", "synthetic:t.json", *argv])
    assert said in capsys.readouterr().err


def test_a_synthetic_camera_over_one_half_sees_that_half(tmp_path: Path) -> None:
    truth = tmp_path / "truth.json"
    write_truth(truth, now_truth(2000.0, 1000.0, {"k1": (500.0, 500.0, 0.0)}))
    source = open_source(f"synthetic:{truth}", grid=(3, 2), over=(0.0, 0.0, 1100.0, 1000.0))
    source.open()
    assert source.read().shape == (480, 640, 3)
    # Straight down over the half's centre, 1.12 times the half's height in view.
    matrix = source.camera_matrix
    assert matrix is not None
    assert matrix[0, 0] == pytest.approx(1500.0 * 480 / (1000.0 * 1.12))
