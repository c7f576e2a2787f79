"""An agent context may hear everything its recorder records, in a lab with access control.

The routers' rules (services/lab/zsecurity.py, from common/dataflow.py) deny a
declaration whose key no grant of the role includes: a recorder subscribing to
a key its role was not granted records nothing from it, silently, on every
multi-host lab (the one-machine lab runs without access control, so only this
check sees it).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import zenoh

from common import keys
from common.recording.store import RecordingStore
from services.context.agent_queue import ControlJob, RunningJob
from services.context.recorder import SlotRecorder
from services.lab.zsecurity import ROLE_GRANTS


class _Declarations:
    """A session that only notes the keys subscribed to."""

    def __init__(self) -> None:
        self.subscribed: list[str] = []

        self.undeclared = 0

    def declare_subscriber(self, key: str, handler: Any, **_: Any) -> Any:
        self.subscribed.append(key)
        return self

    def undeclare(self) -> None:
        self.undeclared += 1


def _granted(role: str, verb: str, key: str) -> bool:
    root = keys.realm_root("lab")
    declared = zenoh.KeyExpr(key)
    return any(
        zenoh.KeyExpr(f"{root}/{pattern}").includes(declared)
        for grant in ROLE_GRANTS[role]
        if grant.verb == verb
        for pattern in grant.keys
    )


def test_the_agent_role_may_subscribe_to_every_key_its_recorder_records(tmp_path: Path) -> None:
    session = _Declarations()
    recorder = SlotRecorder(
        session,  # type: ignore[arg-type]
        "lab",
        "arena",
        "arena1",
        RecordingStore(tmp_path, keep=3),
        bytes(32),
        logging.getLogger("test"),
    )
    recorder.start()
    try:
        always = list(session.subscribed)
        # The world's frames and samples and the cameras' videos only while a slot is
        # recorded: a world builds no frame, a camera encodes no video, no one reads.
        assert keys.world_frame("lab", "arena1") not in always
        job = ControlJob("r1", "k0", "alice", b"\x01" * 16, "remote")
        recorder.run_started(
            RunningJob(job, "L1", b"\x01" * 16, time.time(), time.time() + 60), "alice"
        )
        assert session.subscribed[len(always) :] == [
            keys.world_frame("lab", "arena1"),
            keys.world_samples("lab", "arena1"),
            keys.camera_all("lab", "arena1"),
        ]
        denied = [key for key in session.subscribed if not _granted("agent", "sub", key)]
        assert not denied, f"the agent role may not subscribe to: {denied}"
    finally:
        recorder.close(timeout=2.0)
    assert session.undeclared == len(session.subscribed), "every subscription undeclared"
