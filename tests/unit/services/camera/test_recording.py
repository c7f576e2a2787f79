"""A video file is a recording, not a live camera: its own timeline, a final end (unless it
loops, and then its timeline carries on), and corrupt frames said by number and skipped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.camera.sources import Recording, SourceEnded, open_source
from tests.kit.videos import write_video

FPS = 100.0  # a quick file: the recording plays at its own rate


def video(path: Path, frames: int, corrupt: range = range(0)) -> Path:
    return write_video(path, frames, FPS, corrupt)


def play(source: Recording) -> tuple[list[float], list[int]]:
    stamps, shades = [], []
    source.open()
    with pytest.raises(SourceEnded, match="ended after"):
        while True:
            frame = source.read()
            assert source.captured_at is not None
            stamps.append(source.captured_at)
            shades.append(int(frame[60, 80, 0]))
    return stamps, shades


def test_a_file_is_stamped_with_its_own_timeline_and_its_end_is_final(tmp_path: Path) -> None:
    source = open_source(str(video(tmp_path / "a.avi", 12)))
    assert isinstance(source, Recording) and source.paces_itself
    stamps, _ = play(source)
    assert len(stamps) == 12
    assert np.allclose(np.array(stamps) - stamps[0], np.arange(12) / FPS, atol=1e-6)
    with pytest.raises(SourceEnded, match="give --loop to play it again"):
        source.open()  # an ended recording is not opened again


def test_fps_samples_the_files_timeline_instead_of_slowing_it(tmp_path: Path) -> None:
    source = open_source(str(video(tmp_path / "a.avi", 30)), sample_fps=25.0)
    assert isinstance(source, Recording)
    stamps, _ = play(source)
    assert np.allclose(np.diff(stamps), 0.04, atol=1e-6)  # every 4th frame of 100 fps
    assert len(stamps) == 8


def test_a_looping_file_carries_its_timeline_on(tmp_path: Path) -> None:
    source = Recording(video(tmp_path / "a.avi", 10), loop=True)
    source.open()
    stamps = []
    for _ in range(25):
        source.read()
        assert source.captured_at is not None
        stamps.append(source.captured_at)
    assert source.loops == 2
    assert np.allclose(np.diff(stamps), 1 / FPS, atol=1e-6)  # never back to the start


def test_corrupt_frames_are_said_by_number_and_skipped(tmp_path: Path) -> None:
    path = video(tmp_path / "a.avi", 40, corrupt=range(20, 25))
    source = Recording(path)
    stamps, shades = play(source)
    assert source.notes() == [
        f"frames 20 to 24 of the video file {path} are corrupt (do not decode): skipped"
    ]
    assert len(stamps) == 35
    assert stamps[20] - stamps[0] == pytest.approx(25 / FPS)  # frame 25 at its own time
    assert abs(shades[20] - 100) <= 3  # and it is frame 25 (shade 4 x 25)
