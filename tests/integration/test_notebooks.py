"""The example notebooks, executed top to bottom by nbclient in a real kernel against a
real lab (router, registry, engine, agent context): what they print, and the live plot
the run drew (PNG frames in its Output widget)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from tests.conftest import Router, wait_for
from tests.kit.agentkit import CTX, start_agent_lab
from tests.kit.lab import PASSWORD, ProcessLab, module_lab
from tests.kit.procs import REPO, wart_env

pytestmark = pytest.mark.one_worker
NOTEBOOKS = REPO / "examples" / "notebooks"


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    with module_lab(module_router, tmp_path_factory.mktemp("lab")) as lab:
        start_agent_lab(lab, slot=3.0)
        yield lab


def execute(notebook: Path, lab: ProcessLab, cwd: Path) -> nbformat.NotebookNode:
    """Run every cell in a fresh kernel whose environment points at ``lab``; the password
    prompt answered by WART_PASSWORD (as in CI)."""
    nb = nbformat.read(notebook, as_version=4)
    env = wart_env(
        {
            "WART_CONNECT": lab.router.endpoint,
            "WART_REALM": lab.router.realm,
            "WART_REGISTRY_KEY": lab.key_hex,
            "WART_PASSWORD": PASSWORD,
        }
    )
    client = NotebookClient(
        nb, timeout=90, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}
    )
    client.execute(env=env)
    return nb


def printed(nb: nbformat.NotebookNode) -> str:
    return "".join(
        out.get("text", "")
        for cell in nb.cells
        if cell.cell_type == "code"
        for out in cell.outputs
        if out.output_type == "stream"
    )


def plotted_frames(nb: nbformat.NotebookNode) -> int:
    """PNG frames held by the notebook's Output widgets (nbclient keeps widget state)."""
    states = nb.metadata.get("widgets", {}).get("application/vnd.jupyter.widget-state+json", {})
    return sum(
        1
        for model in states.get("state", {}).values()
        if model.get("model_name") == "OutputModel"
        for out in model.get("state", {}).get("outputs", [])
        if "image/png" in out.get("data", {})
    )


def test_the_notebooks_drive_plot_and_read_back_the_run(lab: ProcessLab, tmp_path: Path) -> None:
    # 01: log in, read, drive a controller class of a cell for one slot, plot live
    nb = execute(NOTEBOOKS / "01_drive_a_robot.ipynb", lab, tmp_path)
    text = printed(nb)
    assert f"logged in as alice to arena ({lab.router.realm})" in text, text
    assert "robots: k0 k1 k2 k3" in text, text
    assert "proximity: [" in text and "wheel speeds: [" in text, text
    assert "k1: you are next" in text and "k1: your slot started for 3 s" in text, text
    assert "<Run of k1, " in text and ": finished" in text, text
    samples = int(text.split("samples: ")[1].split()[0])
    assert samples > 20, text  # a 3 s slot at the engine's rate
    assert "strongest IR reading per sensor: [" in text, text
    assert plotted_frames(nb) >= 1
    # 02: that run, as the lab recorded it: listed, summarised, plotted, a ROS 2 bag
    recorded = lab.state / "rooms" / "recordings" / CTX / "alice"
    wait_for(lambda: any(recorded.glob("*.summary.json")), 20, "alice's run recorded")
    nb = execute(NOTEBOOKS / "02_a_recorded_run.ipynb", lab, tmp_path)
    text = printed(nb)
    assert "1 recorded run(s)" in text and "  k1-" in text, text
    assert ": finished" in text and "distance: " in text, text
    poses = int(text.split("poses: ")[1].split(",")[0])
    assert poses > 20, text
    assert f"plotted {poses} poses" in text, text
    assert any(
        "image/png" in out.get("data", {}) for cell in nb.cells for out in cell.get("outputs", [])
    )
    assert "ROS 2 bag k1-" in text and "/k1/odom  nav_msgs/msg/Odometry" in text, text
