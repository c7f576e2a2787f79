"""The client install (`pip install wart-lab`, no `lab` extra) drives a simulated robot of a
real lab from a fresh virtualenv, gets its recording, and imports nothing of the lab's."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common.recording import read_recording
from tests.conftest import Router, wait_for
from tests.kit.agentkit import CTX, Poses, start_agent_lab
from tests.kit.client_install import ClientInstall, make_client_install, uv
from tests.kit.lab import PASSWORD, ProcessLab, module_lab

pytestmark = [
    pytest.mark.one_worker,
    pytest.mark.skipif(uv() is None, reason="uv makes the client's virtualenv (./dev has it)"),
]
FORWARD = Path(__file__).with_name("controllers") / "forward.py"


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    with module_lab(module_router, tmp_path_factory.mktemp("lab")) as lab:
        start_agent_lab(lab, slot=2.5)
        yield lab


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> ClientInstall:
    return make_client_install(tmp_path_factory.mktemp("laptop") / "venv")


def test_the_client_install_has_none_of_the_lab_extra(client: ClientInstall) -> None:
    installed = client.installed()
    assert {"wart-lab", "eclipse-zenoh", "msgspec", "pynacl"} <= installed
    lab_only = {"numba", "llvmlite", "pymunk", "viser", "opencv-python-headless", "matplotlib"}
    assert not installed & lab_only
    # a lab command says what to install, no traceback
    engine = client.wart("engine", "--world", "w1")
    assert engine.returncode == 2
    assert "this command needs the lab's services: pip install 'wart-lab[lab]'" in engine.stderr
    assert "Traceback" not in engine.stderr + engine.stdout
    # its help marks the commands it has not
    usage = client.wart("--help").stdout
    assert " *engine " in usage and "  control " in usage and " *control" not in usage
    assert "* needs the lab's services, not in this client install: pip install" in usage
    # the import audit sees a guarded import of a module that is not there
    log = client.root / "audit-check.log"
    guarded = "try:\n    import cv2\nexcept ImportError:\n    pass"
    subprocess.run(
        [client.python, "-c", guarded],
        env=client.env({"WART_LAB_IMPORT_LOG": str(log)}),
        check=True,
    )
    assert log.read_text().split()[1:] == ["cv2"]


def test_wart_control_from_the_client_install_drives_a_simulated_robot(
    lab: ProcessLab, client: ClientInstall, tmp_path: Path
) -> None:
    account = ["--context", CTX, "--user", "alice", *lab.net_args()]
    password = {"WART_PASSWORD": PASSWORD}
    with lab.zsession() as z:
        poses = Poses(z, lab.router.realm)
        start = poses.xy("k0")
        control = client.start(
            "control", ["control", str(FORWARD), "--agent", "k0", *account], tmp_path, password
        )
        wait_for(
            lambda: float(np.linalg.norm(poses.xy("k0") - start)) > 30,
            30,
            f"k0 driven by the client's wart control:\n{control.output()}",
        )
        assert control.popen.wait(30) == 0, control.output()
        poses.close()
    # the context writes the run's recording as the slot ends: listed once written
    names: list[str] = []

    def listed() -> bool:
        done = client.wart("record", "list", *account, env=password)
        assert done.returncode == 0, done.stderr
        names[:] = [line.split()[0] for line in done.stdout.splitlines() if line[:2] == "  "]
        return bool(names)

    wait_for(listed, 20, "alice's recording listed")
    run = tmp_path / "run.mcap"
    got = client.wart("record", "get", names[0], "-o", str(run), *account, env=password)
    assert got.returncode == 0, got.stderr
    recording = read_recording(run)
    assert recording.info is not None and recording.info.user == "alice"
    assert len(recording.commands) > 10
    # a ROS 2 bag needs the ros extra: said before logging in
    bag = client.wart("record", "get", names[0], "--format", "rosbag2", *account)
    assert bag.returncode == 2
    assert "needs the rosbags library: pip install 'wart-lab[ros]'" in bag.stderr
    report = client.wart("report", str(run))
    assert report.returncode == 0 and "distance:" in report.stdout, report.stderr
    assert client.lab_imports() == [], "the client imported the lab's modules"
