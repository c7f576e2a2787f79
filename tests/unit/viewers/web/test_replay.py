"""``wart replay FILE``: help, a clear error for a bad file, and a server that serves the run."""

from __future__ import annotations

import urllib.request
from pathlib import Path

import pytest

from common.recording import read_recording
from common.recording.replay import Player, Timeline
from tests.conftest import free_port
from tests.unit.common.test_recording import _record
from viewers.web.adapters import LabError
from viewers.web.replay import ReplayFeed, ReplayServer, main
from viewers.web.world_feed import MapEdit


def test_help_and_a_bad_file_say_what_is_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0
    assert "Replay a recorded run" in capsys.readouterr().out
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not a recording" * 4)
    assert main([str(junk)]) == 2
    err = capsys.readouterr().err
    assert "not an MCAP recording" in err and "Traceback" not in err
    assert main([str(tmp_path / "missing.mcap")]) == 2
    assert "cannot open" in capsys.readouterr().err


def test_the_feed_draws_the_recorded_poses_and_refuses_edits(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _record(path, seconds=1.0)
    rec = read_recording(path)
    feed = ReplayFeed(Player(Timeline(rec)))
    layout = feed.snapshot()
    assert rec.info is not None and rec.info.agent in layout.robots
    k = layout.robots.index(rec.info.agent)
    for t in (0.0, 0.5, 1e9):
        feed.player.seek(t)
        frame = feed.latest()
        assert frame is not None
        recorded = feed.timeline.at(t).frame
        i = recorded.rows.index(rec.info.agent)
        assert frame.seq == feed.timeline.frame_index(t)
        assert tuple(frame.poses[k, :2]) == pytest.approx((recorded.x[i], recorded.y[i]), abs=1e-3)
    readings = feed.sensors(rec.info.agent)
    assert readings is not None and len(readings.ir) == 8
    assert feed.sensors("someone-else") is None
    with pytest.raises(LabError, match="replay"):
        feed.edit(MapEdit(op="delete", kind="obstacle", ident="x"))


def test_the_server_serves_the_page(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _record(path, seconds=0.5)
    app = ReplayServer(read_recording(path), port=free_port())
    try:
        with urllib.request.urlopen(app.url, timeout=10) as page:
            assert page.status == 200
    finally:
        app.stop()
