"""Sim beside real: example 01 on a simulated Khepera and on the (emulated) real one, compared.

Two worlds loaded from the same map with the robot at the same pose: the
engine's world ``sim`` (the map's k1) and the bridge's world ``real``, whose
robot is an emulated Khepera on a real pty driving a simulated body loaded
from that map; the bridge's odometry starts at the map's pose (as ``wart up``
wires an emulated bridge: services/lab/wiring.py map_pose). Each world has its
own agent context, and each records its slot. The simulated run's recording
is promoted to the real robot (its recorded file queued there); the test
downloads both recordings as a student would and compares them with
``wart report --against``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL, AgentClient
from common.lab_errors import LabError
from common.recording import plots, read_recording
from common.recording.compare import compare
from services.bridge.simbody import SimBody
from services.lab.lab_maps import map_pose
from tests.conftest import REPO, Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    agent_user,
    bridged_robot,
    start_agent_context,
    start_engine,
    start_runner,
)
from tests.kit.lab import ProcessLab, make_lab

pytestmark = needs_sandbox
EXAMPLE = REPO / "examples" / "01_braitenberg.py"
MAP = REPO / "maps" / "maze.json"
SIM, REAL = "sim", "real"  # the worlds
SIM_CTX, REAL_CTX = "arena", "lab"  # their agent contexts


@pytest.fixture
def body() -> Iterator[SimBody]:
    with SimBody.from_map(MAP, "k1", seed=5) as sim:
        yield sim


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path, body: SimBody) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab, MAP.stem, world=SIM)
    x, y, deg = map_pose(MAP)  # where the map puts k1: the body is there, so is the odometry
    link = tmp_path / "khepera0"
    with bridged_robot(lab, body, link, f"{x},{y},{deg}", "--arena-mm", "1500", "1000", world=REAL):
        start_runner(lab)
        start_agent_context(lab, slot=3.0, ctx=SIM_CTX, world=SIM)
        start_agent_context(lab, slot=3.0, ctx=REAL_CTX, world=REAL, account="ctx-lab")
        yield lab


def _run_and_download(
    lab: ProcessLab, client: AgentClient, ctx: str, request_id: str, dest: Path
) -> Path:
    final = client.wait_status(request_id, FINAL, timeout=40)
    assert final is not None and final.status == "finished", final
    summary = lab.state / "rooms" / "recordings" / ctx / "alice" / f"{request_id}.summary.json"
    wait_for(summary.exists, 20, f"the recording of {request_id} in {ctx}")
    return client.download(request_id, dest)


def test_example_01_in_sim_and_on_the_emulated_robot_gives_one_report(
    lab: ProcessLab, procs: Procs, tmp_path: Path
) -> None:
    source = EXAMPLE.read_bytes()
    with agent_user(lab, "alice", SIM_CTX) as sim, agent_user(lab, "alice", REAL_CTX) as real:
        on_sim = sim.queue("k1", "deploy", source=source, filename=EXAMPLE.name)
        sim_file = _run_and_download(lab, sim, SIM_CTX, on_sim.request_id, tmp_path / "sim.mcap")
        # Promote to real: the file recorded with the simulated run, queued on the real robot.
        on_real = real.promote(read_recording(sim_file))
        real_file = _run_and_download(
            lab, real, REAL_CTX, on_real.request_id, tmp_path / "real.mcap"
        )
        remote = read_recording(sim_file)
        remote.source = None  # as a remote run's recording: its code never reached the lab
        with pytest.raises(LabError, match="no controller file to promote"):
            real.promote(remote)
    a, b = read_recording(sim_file), read_recording(real_file)
    assert a.source == source and b.source == source
    assert b.info is not None and b.info.filename == EXAMPLE.name
    assert (
        a.info is not None and a.info.world == SIM and b.info is not None and b.info.world == REAL
    )
    cmp = compare(a, b)
    # Both trajectories are there, start where the map says, and the robot moved in both.
    x, y, _ = map_pose(MAP)
    for side in (cmp.a, cmp.b):
        assert side.frames > 20 and side.samples > 10, side
        assert math.hypot(side.start_pose[0] - x, side.start_pose[1] - y) < 30, side
        assert side.path_mm > 50, side  # Braitenberg cruises ~80 mm/s for most of 3 s
    assert cmp.map_from == "sim"  # the bridge's snapshot has no obstacles; the engine's has
    numbers = [
        cmp.final_pose_error_mm,
        cmp.final_heading_error_rad,
        cmp.path_length_ratio,
        *cmp.ir_mean_diff,
        *cmp.ambient_mean_diff,
    ]
    assert all(v is not None and math.isfinite(v) for v in numbers), cmp
    assert len(cmp.ir_mean_diff) == 8 and len(cmp.ambient_mean_diff) == 8
    assert cmp.aligned_samples > 10
    # The same, from the command line: every number named, and the plots.
    args = ["report", str(sim_file), "--against", str(real_file)]
    if plots.available():
        args += ["--plots", str(tmp_path / "plots")]
    shown = procs.start("report-compare", args)
    assert shown.popen.wait(60) == 0, shown.output()
    text = shown.output()
    for name in (
        "final pose error:",
        "path length ratio:",
        "collisions:",
        "IR mean difference:",
        "ambient mean difference:",
    ):
        assert name in text, text
    if plots.available():
        for kind in ("trajectories", "sensors"):
            png = tmp_path / "plots" / f"sim-vs-real.{kind}.png"
            assert png.stat().st_size > 1000, png
    as_json = procs.start("report-json", [*args[:4], "--json"])
    assert as_json.popen.wait(60) == 0, as_json.output()
    assert '"final_pose_error_mm"' in as_json.output()
