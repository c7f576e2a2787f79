"""The calibration dance on an emulated body, without a lab: a recording to fit, fast.

The emulated Khepera's body (services/bridge/simbody.py) with the true parameters of a
body file drives :class:`~common.controller.calibration.Dance` on a simulated clock; a
camera sees its true pose every 1/15 s with a little noise, its IR readings are
sampled every 0.1 s, and each change of command is noted when it was sent. What comes
out is a :class:`~common.recording.reader.Recording` as a real run's reads back (the
same records), so ``wart calibrate``'s fit runs on it unchanged: the benchmark
(bench/bench_twin.py) and the fit's tests use it; the lab's own recordings of a real
arena are tested end to end in tests/integration/test_calibrate.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.controller.calibration import DANCE_MAX_S, Dance
from common.messages import WorldSnapshot
from common.recording import schema as s
from common.recording.reader import Recording, Stamped
from common.recording.writer import RecordingWriter
from common.sim2d.maps import load_map
from services.bridge.body_truth import BodyTruth
from services.bridge.simbody import SimBody

EMPTY_MAP = Path(__file__).resolve().parents[2] / "maps" / "empty.json"
CAMERA_HZ = 15.0
SAMPLE_S = 0.1


def rehearse(
    body: BodyTruth,
    *,
    seed: int = 0,
    camera_noise_mm: float = 0.3,
    seconds: float | None = None,
    name: str = "rehearsal",
) -> Recording:
    """The dance on ``body`` (at most ``seconds`` of it), recorded as a real run is."""
    clock = [0.0]
    world = load_map(EMPTY_MAP, name="rehearsal", seed=seed, tick_s=0.01)
    sim = SimBody(world, "k1", body=body, clock=lambda: clock[0])
    rng = np.random.default_rng(seed + 1)
    end = DANCE_MAX_S if seconds is None else min(seconds, DANCE_MAX_S)
    dance = Dance()
    rec = Recording(path=Path(f"{name}.mcap"))
    rec.info = s.RunInfo(ctx="rehearsal", world="emulated", agent="k1", user="calibration",
                         request_id=name, mode="deploy", start=0.0, planned_end=end)  # fmt: skip
    rec.snapshots.append(Stamped(0.0, _snapshot(world.width, world.height)))
    sent: tuple[int, int] | None = None
    next_camera = next_sample = 0.0
    while clock[0] < end and not dance.over:
        now = clock[0]
        want = dance.command(now, sim.proximity())
        if want != sent:
            sim.set_speeds(*want)
            command = s.CommandRecord(agent="k1", sender="calibration", auth="mac", speeds=want)
            rec.commands.append(Stamped(now, command))
            sent = want
        if now >= next_camera:
            x, y, h = sim.pose()
            dx, dy = rng.normal(0.0, camera_noise_mm, 2)
            turned = float(rng.normal(0.0, 0.002))
            seen = s.TrackedRobotRecord("k1", float(x + dx), float(y + dy), float(h + turned))
            rec.tracked.append(Stamped(now, s.TrackedRecord(camera="rehearsal", robots=[seen])))
            next_camera += 1.0 / CAMERA_HZ
        if now >= next_sample:
            sample = s.SampleRecord(
                agent="k1",
                tick=sim.ticks,
                sim_time=now,
                proximity=list(sim.proximity()),
                ambient=list(sim.ambient()),
                counters=sim.counters(),
                speeds=sim.speed(),
                leds=[0, 0],
            )
            rec.samples.append(Stamped(now, sample))
            next_sample += SAMPLE_S
        sim.tick()
        clock[0] = now + world.tick_s
    return rec


def _snapshot(width: float, height: float) -> WorldSnapshot:
    return WorldSnapshot(
        world="emulated", tick=0, sim_time=0.0, layout=0, tick_s=0.01, seed=0, width=width,
        height=height, items=[], lights=[], agents=[], rows=[], kind="real",
    )  # fmt: skip


def write_rehearsal(rec: Recording, path: Path) -> Path:
    """``rec`` (a rehearsal) as an MCAP file, as the agent context writes a real run."""
    assert rec.info is not None
    writer = RecordingWriter(path, rec.info)
    for snap in rec.snapshots:
        writer.write(s.SNAPSHOT, snap.record, snap.t)
    for command in rec.commands:
        writer.write(s.commands_topic(command.record.agent), command.record, command.t)
    for tracked in rec.tracked:
        writer.write(s.TRACKED, tracked.record, tracked.t)
    for sample in rec.samples:
        writer.write(s.sensors_topic(sample.record.agent), sample.record, sample.t)
    end = max((x.t for x in rec.tracked), default=0.0)
    writer.finish(s.RunEnd(status="finished", reason="the dance is over", at=end))
    return path
