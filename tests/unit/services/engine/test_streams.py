"""A big world's sensor publishers on demand (EngineService, --streams-up-front).

What an operator relies on: past streams_up_front robots, a robot's publisher
is declared once it is watched or leased, never for a robot the world does
not have, and watchers cannot make the engine declare more than
watched_streams_max of them (each is declared on the sim thread: a client
watching every robot of a 10,000-robot world would stall it for 35 s);
leased robots always get theirs. Zenoh is a stand-in here; the real path is
tests/integration/test_engine.py.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest

from common.sim2d import maps
from services.engine.service import EngineService, EngineSettings, _Stream

MAPS = Path(__file__).parents[4] / "maps"


class Publisher:
    def __init__(self) -> None:
        self.matching_status = type("Status", (), {"matching": False})()
        self.undeclared = False

    def declare_matching_listener(self, callback: Any) -> None:
        pass

    def undeclare(self) -> None:
        self.undeclared = True


class Session:
    def __init__(self) -> None:
        self.declared: list[str] = []

    def declare_publisher(self, key: str, **options: Any) -> Publisher:
        self.declared.append(key.rsplit("/", 2)[-2])
        return Publisher()


def _engine(session: Session) -> EngineService:
    world = maps.load_map(MAPS / "foraging.json", name="w1")  # k0 to k3
    settings = EngineSettings(maps_dir=MAPS, streams_up_front=1, watched_streams_max=2)
    engine = EngineService(session, "lab", world, settings)  # type: ignore[arg-type]
    engine._declare_agent_publishers()  # as on_start does
    return engine


def test_watchers_get_publishers_up_to_the_cap_and_leases_always(
    caplog: pytest.LogCaptureFixture,
) -> None:
    session = Session()
    engine = _engine(session)
    assert session.declared == [], "none up front past streams_up_front"
    caplog.set_level(logging.INFO)
    engine._stream(_Stream("ghost", True))
    engine._stream(_Stream("k0", True))
    engine._stream(_Stream("k1", True))
    engine._stream(_Stream("k2", True))  # a third watched robot: over the cap
    assert session.declared == ["k0", "k1"]
    assert "k2 is watched, but 2 robots' samples are published on demand already" in caplog.text
    engine._stream(_Stream("k3", None))  # leased: past the cap too
    engine._stream(_Stream("k0", False))  # unwatched: its publisher stays
    engine._stream(_Stream("k0", True))
    assert session.declared == ["k0", "k1", "k3"]
    assert "ghost" not in caplog.text
    assert "k3's sensor samples published from now on (leased)" in caplog.text
