"""The lab as containers: the image built here, the pods played by podman, a real client.

One module, one image build per run (deploy/container/build, with overlay
storage: about 90 s on 2 cores from nothing, the checkout's kernels' module
taken; a few seconds when the image is up to date), one lab played
with ``podman kube play`` from ``wart kube render --mode podman``: the router,
the registry (its database on a volume) and arena1 (engine and agent
context), TLS with the lab's certificates and access rules, on the host's
network. A client with the student certificate logs in, joins arena1 and
runs the Braitenberg example on a robot, then uploads it to run in the runner's
sandbox inside its container; the router's pod is killed
and started again: the services rejoin, and the same client, still logged
in, drives again.

What this does not cover (podman does not do it): StatefulSets and Services
(the render's podman mode makes the same pods Deployments on the host's
network), readiness probes and restarts of unhealthy containers (the probe
command is run here by hand, inside a pod), Secrets (podman 4.3 mounts them
still encoded: ConfigMaps here), the Ingress, and a cluster's own
container runtime (podman ignores procMount: the runner's container is privileged
here, where a cluster gets an unmasked /proc in a user namespace of the pod's own).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from common import keys
from common.client.agent_client import FINAL, AgentClient
from common.client.lab_client import LabClient
from common.controller import load_controller
from common.keys import AliveKind
from common.service import close_session
from services.lab.labfile import load
from services.lab.pki import issue_lab
from services.lab.plan import read_registry_key
from services.lab.supervisor import AliveWatch
from services.lab.zsecurity import client_tls
from tests.integration.multihost_probe import Poses, moved, session_for
from tests.kit.procs import REPO, free_port
from tests.kit.waits import wait_for

EXAMPLE = REPO / "examples" / "01_braitenberg.py"
IMAGE = "localhost/wart:latest"
# The flags the image was built with (overlay storage where this kernel mounts it).
FLAGS = (
    subprocess.run(
        [str(REPO / "deploy" / "container" / "podman-flags")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    if shutil.which("podman")
    else []
)
LAB = """
realm = "pods{tag}"
lease_ms = 2000
[security]
pki = "pki"
[arena]
slot_seconds = 4
[[hosts]]
name = "K"
address = "127.0.0.1"
port = {port}
names = ["wart-router"]
arenas = false
[[hosts.services]]
kind = "registry"
[[hosts.services]]
kind = "engine"
world = "arena1"
map = "foraging"
[[hosts.services]]
kind = "runner"
name = "runner"
"""
ROUTER_POD = "wart-router-k-pod-0"
ROUTER = f"{ROUTER_POD}-router"
REGISTRY = "wart-registry-registry-pod-0-registry"
ENGINE = "wart-arena-arena1-pod-0-engine"
RUNNER = "wart-runner-runner-pod-0-runner"
FORK_BOMB = """
import os
from common.controller import Controller
class Forker(Controller):
    def do_work(self, robot):
        robot.set_speeds(0, 0)
        forks = 0
        while True:
            try:
                if os.fork() == 0:
                    os.sched_yield()
                    while True:
                        pass
            except OSError as exc:
                print("fork refused after", forks, "forks:", exc)
                raise SystemExit(0)
            forks += 1
"""


def _unavailable() -> str | None:
    if os.geteuid() != 0:
        return "podman runs as root here (docs/DEPLOY.md, 'On Kubernetes')"
    for tool in ("podman", "mmdebstrap", "runc"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (./dev test installs it)"
    return None


_why = _unavailable()
pytestmark = [
    pytest.mark.xdist_group("podman"),
    # The image's build (minutes on a fresh machine) and the pods' start and removal.
    pytest.mark.timeout(1200),
    *([pytest.mark.skip(reason=_why)] if _why else []),
]


@dataclass
class PodLab:
    lab_path: Path
    pods: Path
    env: dict[str, str]

    def podman(self, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            ["podman", *FLAGS, *args],
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    def pod_state(self, pod: str) -> str:
        return self.podman("pod", "inspect", "--format", "{{.State}}", pod).stdout.strip()

    def start_again(self, pod: str, back: Callable[[], bool], timeout: float) -> int:
        """Start a killed pod until ``back()``; how many starts it took.

        Podman 4.3 gives a played pod the exit policy "stop": once its containers have
        exited, a cleanup process of podman's own stops the pod, in the background. A
        start racing that stop fails ("internal libpod error"), and a start that wins
        is undone by it a moment later (seen here: the router ended by SIGTERM 0.3 s
        after a start that had answered 0, about one kill in three). So the pod is
        started whenever podman says it is stopped, as a cluster's kubelet would.
        """
        deadline = time.monotonic() + timeout
        starts = 0
        while not back():
            assert time.monotonic() < deadline, f"{pod} not back in {timeout:.0f} s\n{self.logs()}"
            if self.pod_state(pod) == "Exited":
                started = self.podman("pod", "start", pod)
                starts += started.returncode == 0
            time.sleep(0.5)
        return starts

    def logs(self) -> str:
        out = []
        for name in (ROUTER, REGISTRY, ENGINE, "wart-arena-arena1-pod-0-agent"):
            text = self.podman("logs", name).stdout + self.podman("logs", name).stderr
            out.append(f"--- {name}\n{text[-2000:]}")
        return "\n".join(out)

    def down(self) -> None:
        """The pods and their volumes (claims, and the ConfigMaps podman keeps as volumes),
        left by this run or a crashed one."""
        self.podman("kube", "down", str(self.pods))
        for obj in yaml.safe_load_all(self.pods.read_text()):
            if obj["kind"] in ("PersistentVolumeClaim", "ConfigMap"):
                self.podman("volume", "rm", "-f", obj["metadata"]["name"])


@pytest.fixture(scope="module")
def pod_lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[PodLab]:
    tmp = tmp_path_factory.mktemp("pods")
    conf = tmp / "containers.conf"
    conf.write_text("[containers]\ndefault_ulimits = []\n")
    env = {**os.environ, "CONTAINERS_CONF": str(conf)}
    t0 = time.monotonic()
    built = subprocess.run(
        [str(REPO / "deploy" / "container" / "build")],
        env=env,
        capture_output=True,
        text=True,
        timeout=1000,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    print(f"image: {time.monotonic() - t0:.0f} s ({built.stderr.strip().splitlines()[-1]})")
    lab_path = tmp / "lab.toml"
    lab_path.write_text(LAB.format(tag=os.getpid(), port=free_port()))
    issue_lab(load(lab_path), say=lambda _text: None)
    pods = tmp / "pods.yaml"
    render = ["kube", "render", "--lab", str(lab_path), "--name", "K", "--mode", "podman"]
    rendered = subprocess.run(
        [sys.executable, "-m", "services.cli", *render],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert rendered.returncode == 0, rendered.stderr
    pods.write_text(rendered.stdout)
    lab = PodLab(lab_path, pods, env)
    lab.down()
    t0 = time.monotonic()
    played = lab.podman("kube", "play", str(pods))
    assert played.returncode == 0, played.stderr
    print(f"played in {time.monotonic() - t0:.0f} s")
    try:
        yield lab
    finally:
        t0 = time.monotonic()
        lab.down()
        lab.podman("image", "prune", "-f")  # an earlier build's image, once no pod uses it
        print(f"removed in {time.monotonic() - t0:.0f} s")


def test_a_client_drives_in_the_pods_lab_and_recovers_when_the_router_is_replaced(
    pod_lab: PodLab,
) -> None:
    lab = load(pod_lab.lab_path)
    world = keys.alive(lab.realm, AliveKind.WORLD, "arena1")
    context = keys.alive(lab.realm, AliveKind.CONTEXT, "arena1")
    session = session_for(
        pod_lab.lab_path, client_tls(lab.security.pki, "student"), lab.hosts[0].endpoint, 2000
    )
    watch = AliveWatch(session, keys.alive_all(lab.realm))
    try:
        # The engine loads its kernels compiled in the image: serving in seconds.
        assert watch.wait(world, 120) and watch.wait(context, 60), pod_lab.logs()
        # The pods' probe, inside a pod: its TLS certificate, the router's access rules.
        probe = pod_lab.podman("exec", ENGINE, "wart", "probe", "context", "arena1")
        assert probe.returncode == 0, probe.stderr
        assert "context arena1 is alive" in probe.stdout
        first = re.search(r"password (\S+)", pod_lab.podman("logs", REGISTRY).stdout)
        assert first is not None, pod_lab.logs()
        controller = load_controller(EXAMPLE)
        with LabClient(session, lab.realm, read_registry_key(lab), presence=False) as client:
            client.login("admin", first.group(1))
            poses = Poses(session, lab.realm, "arena1")
            agent = poses.rows[0]
            agents = AgentClient(client, "arena1").join()
            start = poses.xy(agent)
            driven = agents.drive(agent, controller)
            assert driven.status == "finished", driven
            assert moved(start, poses.xy(agent)) > 50  # Braitenberg: ~80 mm/s for 4 s
            # Uploaded, it runs in the runner's container, in a sandbox of its own.
            assert watch.wait(keys.alive(lab.realm, AliveKind.RUNNER, "runner"), 60)
            start = poses.xy(agent)
            queued = agents.queue(agent, "deploy", source=EXAMPLE.read_bytes())
            deployed = agents.wait_status(queued.request_id, FINAL, timeout=60)
            assert deployed is not None and deployed.status == "finished", (
                deployed,
                pod_lab.podman("logs", RUNNER).stderr[-3000:],
            )
            assert moved(start, poses.xy(agent)) > 50
            # The runner is not root here: its sandbox limits processes from inside,
            # and a fork bomb stops at that limit whatever else the uid runs.
            printed: list[str] = []
            agents.on_output = lambda out: printed.extend(out.lines)
            queued = agents.queue(agent, "deploy", source=FORK_BOMB.encode())
            bombed = agents.wait_status(queued.request_id, FINAL, timeout=60)
            assert bombed is not None and bombed.status == "finished", bombed
            wait_for(lambda: any("fork refused" in line for line in printed), 15, "the refusal")
            # The router's pod killed and started again: every link drops, the
            # services reconnect and their tokens come back, this client too.
            killed = pod_lab.podman("pod", "kill", ROUTER_POD)
            assert killed.returncode == 0, killed.stderr
            t0 = time.monotonic()
            deadline = t0 + 10
            while watch.present(world) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert not watch.present(world), "the world stayed while its router was down"
            starts = pod_lab.start_again(ROUTER_POD, lambda: watch.present(world), 60)
            assert watch.wait(world, 1) and watch.wait(context, 60), pod_lab.logs()
            print(
                f"arena1 back {time.monotonic() - t0:.1f} s after the router was killed"
                f" (the pod started {starts} times)"
            )
            start = poses.xy(agent)
            again = agents.drive(agent, controller)
            assert again.status == "finished", again
            assert moved(start, poses.xy(agent)) > 50
            agents.leave()
            poses.close()
    finally:
        watch.close()
        close_session(session)
