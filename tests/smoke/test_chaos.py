"""Chaos: kill -9 services of a running lab with chat clients attached; all come back whole.

The figures (time until back, until the clients are whole) are printed here and
measured properly by bench/bench_chaos.py; this asserts what a user cares about:
no user action is needed, and no acknowledged line is lost.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.kit.chaos import Chaos, DeployProbe, running_lab

# A whole lab, every service killed in turn and waited back: its hang guard is longer.
pytestmark = pytest.mark.timeout(300)

# Every service a chat client depends on, the router first.
VICTIMS = ("router", "context chat lobby", "registry", "engine arena1", "context agent arena")


def test_clients_come_back_by_themselves_after_each_kill(tmp_path: Path) -> None:
    with running_lab(tmp_path) as lab:
        chaos = Chaos(lab, deadline_s=30.0)
        deploy = DeployProbe(lab, lab.admin_password())
        try:
            assert deploy.output.wait("running on k0", 60), deploy.output.lines
            outcomes = [chaos.kill(service) for service in VICTIMS]
            for out in outcomes:
                print(f"{out.service}: back {out.back_s} s, clients whole {out.whole_s} s")
            lost = chaos.lost_lines()
            # the deployed controller lived through all of that; its runner's death it
            # cannot live through, and the student is told so rather than left waiting
            assert deploy.popen.poll() is None, deploy.output.lines
            runner = chaos.kill("runner runner")
            ending = deploy.ending(30)
        finally:
            deploy.close()
            chaos.close()
    assert runner.back_s is not None
    assert "runner runner stopped" in ending, ending
    for out in outcomes:
        assert out.back_s is not None, f"{out.service} did not come back: {out.note}"
        assert out.whole_s is not None, f"chat clients not whole after {out.service}'s kill"
    assert not lost, f"acknowledged lines lost: {lost}"
    assert len(chaos.acknowledged) >= 2 * len(VICTIMS)
