"""A three-host lab in network namespaces, routers meshed over mutual TLS with access rules.

A: router, registry, chat lobby, web viewer (takes no arenas); B: router, a second
web viewer, engine arena1 with its agent context, the runner; C: router, bridge real1 driving an
emulated Khepera, agent context robots for it (its controllers run on B's
runner). Each host runs ``wart host`` from one lab file; probes
(tests/integration/multihost_probe.py) run inside the namespaces. Transport
lease 2 s, so a cut link is noticed within about 2 s.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from services.lab.certs import init_ca, issue
from services.lab.labfile import load
from services.lab.pki import issue_lab
from tests.kit import netns

# One worker builds the three-host network once for the module (two built it twice: 20 s).
pytestmark = [pytest.mark.netns, pytest.mark.one_worker]

_reason = netns.available()
if _reason is not None:
    print(f"multi-host tests skipped: {_reason}")
    pytestmark.append(pytest.mark.skip(reason=f"multi-host tests skipped: {_reason}"))

LAB = """
realm = "{realm}"
lease_ms = 2000
state_dir = "state"
[security]
pki = "pki"
[limits]
max_cpu_percent = 100.0
load_period_s = 1.0
max_arenas_per_host = 3
[arena]   # 3 s slots so a test drives quickly
slot_seconds = 3
[[hosts]]
name = "A"
address = "{a}"
arenas = false
[[hosts.services]]
kind = "registry"
[[hosts.services]]
kind = "chat"
name = "lobby"
[[hosts.services]]
kind = "viewer"
http_host = "{a}"
[[hosts]]
name = "B"
address = "{b}"
[[hosts.services]]
kind = "viewer"   # a second web viewer: any viewer serves any user of the lab
http_host = "{b}"
[[hosts.services]]
kind = "engine"
world = "arena1"
map = "foraging"
[[hosts.services]]
kind = "runner"
name = "run1"
[[hosts]]
name = "C"
address = "{c}"
[[hosts.services]]
kind = "bridge"
world = "real1"
emulate = "empty"
[[hosts.services]]
kind = "agent"
name = "robots"
world = "real1"
slot_seconds = 6
"""


@dataclass
class MultiLab:
    net: netns.Network
    lab_path: Path
    tmp: Path
    hosts: dict[str, subprocess.Popen[bytes]]

    def host(self, name: str) -> netns.HostNet:
        return self.net.hosts["ABC".index(name)]

    @property
    def password_file(self) -> Path:
        return self.tmp / "state" / "A" / "admin-password.txt"

    def probe(self, on: str, verb: str, *args: str, timeout: float = 40.0) -> dict:
        proc = self.start_probe(on, verb, *args)
        try:
            proc.wait(timeout)
        finally:
            _stop(proc)
        return self.result(proc, verb)

    def start_probe(self, on: str, verb: str, *args: str) -> subprocess.Popen[bytes]:
        log = self.tmp / f"probe-{verb}-{on}-{time.monotonic_ns()}.log"
        proc = self.host(on).popen(
            ["-m", "tests.integration.multihost_probe", verb, str(self.lab_path), *args], log
        )
        proc.log_path = log  # type: ignore[attr-defined]
        return proc

    def wait_line(self, proc: subprocess.Popen[bytes], needle: str, timeout: float = 20.0) -> None:
        log: Path = proc.log_path  # type: ignore[attr-defined]
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if needle in log.read_text(errors="replace"):
                return
            if proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"probe never printed {needle!r}:\n{log.read_text(errors='replace')}")

    def result(self, proc: subprocess.Popen[bytes], verb: str) -> dict:
        log: Path = proc.log_path  # type: ignore[attr-defined]
        text = log.read_text(errors="replace")
        for line in text.splitlines():
            if line.startswith("RESULT "):
                return json.loads(line[len("RESULT ") :])
        raise AssertionError(f"probe {verb} failed:\n{text}\n{self.logs()}")

    def logs(self, *services: str) -> str:
        """Each host's log, then the last lines of its viewer's and chat room's own logs
        (what a failed probe of the page or the chat needs to be read), and of the logs
        whose names hold one of ``services``."""
        out = []
        for path in sorted((self.tmp).glob("host-*.log")):
            out.append(f"--- {path.name}\n{path.read_text(errors='replace')[-3000:]}")
        for path in sorted((self.tmp / "state").glob("*/**/*.log")):
            if any(name in path.name for name in ("viewer", "lobby", *services)):
                tail = path.read_text(errors="replace").splitlines()[-30:]
                out.append(f"--- {path.relative_to(self.tmp)}\n" + "\n".join(tail))
        return "\n".join(out)


def _stop(proc: subprocess.Popen[bytes], timeout: float = 15.0) -> None:
    """SIGTERM the process group (ip netns exec + python), SIGKILL what is left."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)
    except ProcessLookupError:
        pass


def _wait_ready(log: Path, proc: subprocess.Popen[bytes], timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        text = log.read_text(errors="replace") if log.exists() else ""
        if "is running. Press Ctrl-C" in text:
            return
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise AssertionError(f"wart host did not come up:\n{log.read_text(errors='replace')}")


# The liveliness tokens every host must see before the tests start (kind:id).
MESH = (
    "registry:registry",
    "world:arena1",
    "context:arena1",
    "runner:run1",
    "world:real1",
    "context:robots",
)


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[MultiLab]:
    tmp = tmp_path_factory.mktemp("multihost")
    with netns.Network(3) as net:
        a, b, c = (h.address for h in net.hosts)
        lab_path = tmp / "lab.toml"
        lab_path.write_text(LAB.format(realm=f"m{net.tag}", a=a, b=b, c=c))
        issue_lab(load(lab_path), say=lambda _text: None)
        procs: dict[str, subprocess.Popen[bytes]] = {}
        try:
            # B and C first: their routers retry the link to A until A is up.
            for name in ("A", "B", "C"):
                log = tmp / f"host-{name}.log"
                procs[name] = net.hosts["ABC".index(name)].popen(
                    ["-m", "services.cli", "host", "--lab", str(lab_path), "--name", name], log
                )
            for name, proc in procs.items():
                _wait_ready(tmp / f"host-{name}.log", proc)
            multi = MultiLab(net, lab_path, tmp, procs)
            # Each host running is not the mesh formed: wait until every host sees
            # the services the tests use on the others (a condition, not a pause).
            for name in ("A", "B", "C"):
                seen = multi.probe(name, "await", name, *MESH, timeout=120.0)
                assert seen["missing"] == [], f"from {name}: {seen}\n{multi.logs()}"
            yield multi
        finally:
            for proc in procs.values():
                _stop(proc)
            # Children orphaned by a crash: only processes whose command line names
            # this test's own directory (configs, logs), never anyone else's.
            leftovers = subprocess.run(
                ["pgrep", "-f", str(tmp)], capture_output=True, text=True
            ).stdout.split()
            for pid in leftovers:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(pid), signal.SIGKILL)


def test_services_talk_across_hosts_and_the_doctor_sees_the_mesh(lab: MultiLab) -> None:
    # From C: log in (registry on A), the directory lists A's chat room, and the
    # engine on B answers a snapshot.
    seen = lab.probe("C", "across", "C", str(lab.password_file))
    assert "lobby" in seen["contexts"]
    assert seen["snapshot_agents"] > 0
    doctor = lab.host("A").popen(
        ["-m", "services.cli", "doctor", "--lab", str(lab.lab_path)], lab.tmp / "doctor.log"
    )
    code = doctor.wait(60)
    out = (lab.tmp / "doctor.log").read_text()
    assert code == 0, out
    assert "router B: rtt" in out and "links to A" in out
    for line in (
        "engine arena1 on B is alive",
        "agent context arena1 on B is alive",
        "runner run1 on B is alive",
        "bridge real1 on C is alive",
        "agent context robots on C is alive",
        "viewer on A is alive",
        "viewer on B is alive",
        "arena arena1 on B: agent context alive",
    ):
        assert line in out, out


def test_a_student_on_a_queues_and_drives_robots_on_b_and_c(lab: MultiLab) -> None:
    # On B: the example controller, uploaded from A, runs in B's runner sandbox and
    # moves a simulated robot. On C: the same upload (run on B, commanding C's
    # bridge across two links) and a remote drive from A move the emulated Khepera.
    seen = lab.probe("A", "drive", "A", str(lab.password_file), timeout=75)
    assert seen["arena1_deploy"] == "finished", seen
    assert seen["real1_deploy"] == "finished", seen
    assert seen["real1_remote"] == "finished", seen
    # Braitenberg cruises at about 80 mm/s: a 3 s slot covers well over 50 mm on a quiet
    # machine. A busy one starts the sandbox late in the slot (38 mm in a CI run), so the
    # bound is motion against the forged commands' none below (under 10 mm). real1's slots
    # are 6 s: its deploy starts a sandbox on B that drives C's bridge across two links.
    # real1's poses come from C's camera: 0 mm there (twice in CI) was the camera not
    # knowing k1 (it read the world just before the bridge added it, and read it again
    # only 30 s later); it now reads the world again on its layout news (test_camera).
    why = f"{seen}\n{lab.logs('run1', 'real1', 'robots')}"
    assert seen["arena1_deploy_mm"] > 20, why
    assert seen["real1_deploy_mm"] > 20, why
    assert seen["real1_remote_mm"] > 20, why
    # Then the same student, logged in but holding no lease, sends well-formed
    # sealed commands for 1.5 s at a speed that would cover over 200 mm: neither
    # the engine nor the bridge obeys them.
    assert seen["arena1_forged_mm"] < 10, seen
    assert seen["real1_forged_mm"] < 10, seen
    print(f"moved (mm): {seen}")


def test_two_viewers_on_two_hosts_serve_the_same_lab(lab: MultiLab) -> None:
    # From C, as two browsers would: stu1 on A's viewer, stu2 on B's (headless clients
    # speaking viser's protocol). Each logs in through its page, both chat in the
    # lobby and each sees the other's line, both watch arena1 and see the same robots.
    a, b = lab.host("A").address, lab.host("B").address
    seen = lab.probe("C", "viewers", str(lab.password_file), a, b, timeout=150)
    assert seen["chat_a_saw_b"] and seen["chat_b_saw_a"], seen
    assert seen["same_world"] and seen["robots"] > 0, seen


def test_a_process_without_a_valid_certificate_cannot_join(lab: MultiLab) -> None:
    rogue = lab.tmp / "rogue"
    init_ca(rogue)
    issue(rogue, "engine", alt_names=[lab.host("A").address])
    refused = lab.probe("C", "join", "A", str(rogue), "engine")
    assert refused["joined"] is False
    # The control: the lab's own student certificate joins.
    pki = load(lab.lab_path).security.pki
    assert lab.probe("C", "join", "A", str(pki / "clients"), "student")["joined"] is True


def test_a_student_cannot_publish_frames_or_leases_even_well_formed(lab: MultiLab) -> None:
    done = lab.tmp / "forgeries-sent"
    frames = lab.start_probe("C", "watch-frames", "C", "90", str(done))
    leases = lab.start_probe("B", "watch-leases", "B", "90", str(done))
    try:
        lab.wait_line(frames, "READY")
        lab.wait_line(leases, "READY")
        lab.probe("A", "forge", "A", "student", str(lab.password_file), "client")
        # Control: an agent context's certificate may publish leases.
        lab.probe("B", "forge", "B", "agent", str(lab.password_file), "host")
        done.touch()
        frames.wait(30)
        leases.wait(30)
    finally:
        _stop(frames)
        _stop(leases)
    counted = lab.result(frames, "watch-frames")
    assert counted["real"] > 0, "the engine's own frames must arrive (the control)"
    assert counted["forged"] == 0, "a student's frame went through the routers"
    holders = lab.result(leases, "watch-leases")["holders"]
    assert holders.get("agent", 0) > 0, "the agent's leases must arrive (the control)"
    assert "student" not in holders, "a student's lease went through the routers"


def test_arena_requested_from_a_starts_on_b_or_c_and_appears(lab: MultiLab) -> None:
    started = lab.probe("A", "arena", "A", str(lab.password_file), "extra1", timeout=90)
    assert started["host"] in ("B", "C")
    assert started["seen"] is True
    assert started["kind"] == "agent", "the arena's agent context is not in the directory"
    assert "stopped" in started["stopped"]


def _count(proc: subprocess.Popen[bytes], needle: str) -> int:
    return proc.log_path.read_text().count(needle)  # type: ignore[attr-defined]


def test_cutting_b_link_drops_its_world_and_context_then_they_return(lab: MultiLab) -> None:
    host_logs = {name: lab.tmp / f"host-{name}.log" for name in "ABC"}
    before = {n: p.read_text(errors="replace").count("restarting") for n, p in host_logs.items()}
    follow = lab.start_probe("A", "follow", "A", "world", "arena1", "30")
    listing = lab.start_probe("A", "dir-follow", "A", str(lab.password_file), "arena1", "30")
    try:
        lab.wait_line(follow, "READY")
        lab.wait_line(follow, "EVENT put")
        lab.wait_line(listing, "EVENT listed")
        cut = time.monotonic()
        lab.host("B").down()
        try:
            lab.wait_line(follow, "EVENT delete", timeout=10)
            gone_after = time.monotonic() - cut
            lab.wait_line(listing, "EVENT unlisted", timeout=10)
            unlisted_after = time.monotonic() - cut
        finally:
            lab.host("B").up()
        back = time.monotonic()
        assert _count(follow, "EVENT put") == 1
        deadline = time.monotonic() + 20
        while _count(follow, "EVENT put") < 2 or _count(listing, "EVENT listed") < 2:
            assert time.monotonic() < deadline, "arena1 did not come back after the link returned"
            time.sleep(0.1)
        back_after = time.monotonic() - back
    finally:
        _stop(follow)
        _stop(listing)
    assert gone_after < 2.0 * 2 + 1.0, f"took {gone_after:.1f} s to notice (lease 2 s)"
    # The registry drops a context with its token: the same bound, plus a poll.
    assert unlisted_after < 2.0 * 2 + 1.5, f"the directory kept arena1 {unlisted_after:.1f} s"
    print(
        f"arena1 left after {gone_after:.1f} s (directory {unlisted_after:.1f} s), "
        f"came back {back_after:.1f} s after the link"
    )
    after = {n: p.read_text(errors="replace").count("restarting") for n, p in host_logs.items()}
    assert after == before, "a service restarted"
