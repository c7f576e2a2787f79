"""Probes the multi-host tests run inside a host's network namespace.

    python -m tests.integration.multihost_probe VERB LAB_FILE [ARGS...]

Each verb prints what it saw as one JSON line (``RESULT {...}``) and exits 0,
or prints why and exits 1. The test process itself lives outside the
namespaces, so everything that talks to the lab runs here.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import numpy as np

from common import keys
from common.client.lab_client import LabClient
from common.keys import AliveKind
from common.messages import AgentCommand, Lease, PackedArray, WorldFrame, decode, encode
from common.messages.world import WorldSnapshot
from common.service import close_session, open_session
from services.commands.arena import new_arena, stop_arena
from services.lab.labfile import load
from services.lab.plan import read_registry_key
from services.lab.zsecurity import TlsFiles, client_tls, host_tls, zenoh_security

FORGED_TICK = 987_654
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "01_braitenberg.py"


class Poses:
    """The newest frame of a world, seen from this host (callback kept short)."""

    def __init__(self, session, realm: str, world: str) -> None:
        self.rows: list[str] = []
        for reply in session.get(keys.world_snapshot(realm, world), timeout=10.0):
            if reply.ok is not None:
                self.rows = decode(reply.ok.payload, WorldSnapshot).rows
        self._raw: bytes | None = None
        self._lock = threading.Lock()

        def on(sample) -> None:
            with self._lock:
                self._raw = bytes(sample.payload.to_bytes())

        self.sub = session.declare_subscriber(keys.world_frame(realm, world), on)
        deadline = time.monotonic() + 10
        while self._raw is None and time.monotonic() < deadline:
            time.sleep(0.05)

    def xy(self, agent: str) -> tuple[float, float]:
        with self._lock:
            raw = self._raw
        if raw is None:
            raise RuntimeError("no frame of this world arrived")
        pose = decode(raw, WorldFrame).poses.to_numpy()[self.rows.index(agent)]
        return float(pose[0]), float(pose[1])

    def close(self) -> None:
        self.sub.undeclare()


def moved(before: tuple[float, float], after: tuple[float, float]) -> float:
    return float(np.hypot(after[0] - before[0], after[1] - before[1]))


def result(**values: object) -> int:
    print("RESULT " + json.dumps(values), flush=True)
    return 0


STUDENT_PASSWORD = "viewer-test-pw"
VIEWER_PORT = 8080  # the lab file's default


async def _two_viewers(at_a: str, at_b: str) -> dict[str, object]:
    """stu1 on A's viewer, stu2 on B's: log in, chat both ways in the lobby, watch arena1."""
    from tests.kit.viser_client import ViserClient

    on_a = ViserClient(f"ws://{at_a}:{VIEWER_PORT}", "viewer-A")
    on_b = ViserClient(f"ws://{at_b}:{VIEWER_PORT}", "viewer-B")
    try:
        await on_a.connect()
        await on_b.connect()
        await on_a.log_in("stu1", STUDENT_PASSWORD)
        await on_b.log_in("stu2", STUDENT_PASSWORD)
        await on_a.join_room("lobby")
        await on_b.join_room("lobby")
        await on_a.say("hello from A")
        await on_b.wait_for(lambda: on_b.markdown_containing("hello from A"), 30)
        await on_b.say("hello from B")
        await on_a.wait_for(lambda: on_a.markdown_containing("hello from B"), 30)
        await on_a.join("arena1")
        await on_b.join("arena1")

        def same_world() -> bool:
            # The same engine's robots, drawn from two viewers: equal counts, and each
            # robot within 30 mm of itself (frames a tick or two apart may differ).
            a, b = on_a.latest, on_b.latest
            if a is None or b is None or a.positions.shape != b.positions.shape:
                return False
            return bool(np.abs(a.positions - b.positions).max() < 0.03)

        same = await on_a.wait_for(same_world, 30)
        robots = len(on_a.latest.positions) if on_a.latest is not None else 0
        return {
            "chat_a_saw_b": on_a.markdown_containing("hello from B") is not None,
            "chat_b_saw_a": on_b.markdown_containing("hello from A") is not None,
            "same_world": bool(same),
            "robots": robots,
            "frames": [on_a.frames, on_b.frames],
        }
    finally:
        await on_a.close()
        await on_b.close()


def session_for(lab_path: Path, tls: TlsFiles | None, endpoint: str, lab_lease: int):
    from common.zconfig import NetworkOptions

    extra: dict[str, object] = {}
    if tls is not None:
        link = zenoh_security(tls, lease_ms=lab_lease)["transport"]["link"]
        extra = {"transport/link/tls": link["tls"]}
    lab = load(lab_path)
    return open_session(
        NetworkOptions(realm=lab.realm, connect=(endpoint,), extra=extra), wait=5.0, quiet=True
    )


def _watch_until(seconds: float, done: Path | None) -> None:
    """Watch for ``seconds`` at most, or until ``done`` appears and a second more.

    The test writes ``done`` once the probes it watches for have returned, so a slow
    start of those probes on a busy machine does not fall outside the window; the
    extra second lets their last messages, already sent, arrive.
    """
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if done is not None and done.exists():
            time.sleep(1.0)
            return
        time.sleep(0.05)


def main() -> int:
    verb, lab_path = sys.argv[1], Path(sys.argv[2])
    args = sys.argv[3:]
    lab = load(lab_path)
    realm, pki = lab.realm, lab.security.pki

    if verb == "join":
        # join HOST CERTDIR NAME: can a process with this certificate join HOST's router?
        host, cert_dir, name = args
        tls = TlsFiles(
            pki / "ca.pem", Path(cert_dir) / f"{name}.pem", Path(cert_dir) / f"{name}.key"
        )
        try:
            s = session_for(lab_path, tls, lab.host(host).endpoint, lab.lease_ms)
        except ConnectionError as exc:
            return result(joined=False, why=str(exc)[:200])
        close_session(s)
        return result(joined=True)

    if verb == "viewers":
        # viewers PASSWORD_FILE ADDRESS_A ADDRESS_B: two students, one on the web viewer
        # of each host (a browser's address can name either), chat and watch arena1.
        password_file, at_a, at_b = args
        s = session_for(lab_path, client_tls(pki, "student"), lab.host("C").endpoint, lab.lease_ms)
        try:
            with LabClient(s, realm, read_registry_key(lab), presence=False) as admin:
                admin.login("admin", Path(password_file).read_text().strip())
                known = {u.name for u in admin.list_users()}
                for user in ("stu1", "stu2"):
                    if user not in known:
                        admin.add_user(user, STUDENT_PASSWORD)
        finally:
            close_session(s)
        from tests.kit.viser_client import run_in_thread

        return result(**run_in_thread(_two_viewers(at_a, at_b)))

    if verb == "across":
        # across HOST PASSWORD_FILE: log in (registry on A) and fetch the snapshot of
        # arena1 (engine on B) from HOST, with the student certificate.
        host, password_file = args
        s = session_for(lab_path, client_tls(pki, "student"), lab.host(host).endpoint, lab.lease_ms)
        try:
            with LabClient(s, realm, read_registry_key(lab), presence=False) as client:
                client.login("admin", Path(password_file).read_text().strip())
                directory = client.directory()
                replies = [
                    r.ok.payload
                    for r in s.get(keys.world_snapshot(realm, "arena1"), timeout=5)
                    if r.ok is not None
                ]
                snap = decode(replies[0], WorldSnapshot) if replies else None
                return result(
                    contexts=[c.ctx for c in directory.contexts],
                    snapshot_agents=len(snap.agents) if snap else 0,
                )
        finally:
            close_session(s)

    if verb == "watch-frames":
        # watch-frames HOST SECONDS: count real and forged frames of arena1 seen from HOST.
        host, seconds = args[0], float(args[1])
        s = session_for(lab_path, client_tls(pki, "admin"), lab.host(host).endpoint, lab.lease_ms)
        counts = {"real": 0, "forged": 0}

        def on_frame(sample) -> None:
            frame = decode(sample.payload, WorldFrame)
            counts["forged" if frame.tick == FORGED_TICK else "real"] += 1

        sub = s.declare_subscriber(keys.world_frame(realm, "arena1"), on_frame)
        print("READY", flush=True)
        _watch_until(seconds, Path(args[2]) if len(args) > 2 else None)
        sub.undeclare()
        close_session(s)
        return result(**counts)

    if verb == "watch-leases":
        # watch-leases HOST SECONDS: as an engine of HOST, count leases of arena1 by holder.
        host, seconds = args[0], float(args[1])
        s = session_for(
            lab_path, host_tls(pki, host, "engine"), lab.host(host).local_endpoint, lab.lease_ms
        )
        holders: dict[str, int] = {}
        lock = threading.Lock()

        def on_lease(sample) -> None:
            from common.messages import AuthEnvelope

            env = decode(sample.payload, AuthEnvelope)
            lease = decode(env.body, Lease)
            with lock:
                holders[lease.holder_user] = holders.get(lease.holder_user, 0) + 1

        sub = s.declare_subscriber(keys.agent_lease_all(realm, "arena1"), on_lease)
        print("READY", flush=True)
        _watch_until(seconds, Path(args[2]) if len(args) > 2 else None)
        sub.undeclare()
        close_session(s)
        return result(holders=holders)

    if verb == "forge":
        # forge HOST CERT PASSWORD_FILE ROLE: publish a frame and a sealed lease with
        # the given certificate (a student's, or an agent context's as a control).
        host, cert, password_file, role = args
        tls = client_tls(pki, cert) if role == "client" else host_tls(pki, host, cert)
        endpoint = lab.host(host).endpoint if role == "client" else lab.host(host).local_endpoint
        s = session_for(lab_path, tls, endpoint, lab.lease_ms)
        try:
            with LabClient(s, realm, read_registry_key(lab), presence=False) as client:
                client.login("admin", Path(password_file).read_text().strip())
                assert client.session is not None
                now = time.time()
                frame = WorldFrame(
                    world="arena1",
                    tick=FORGED_TICK,
                    sim_time=0.0,
                    layout=0,
                    poses=PackedArray.from_numpy(np.zeros((4, 3), np.float32)),
                    agent_state=PackedArray.from_numpy(np.zeros((4, 4), np.uint8)),
                    lights=PackedArray.from_numpy(np.zeros((1,), np.uint8)),
                )
                lease = Lease(
                    lease_id=f"forged-{cert}",
                    world="arena1",
                    agent="k0",
                    holder_user=cert,
                    holder_session=client.session.session_id,
                    start=now,
                    end=now + 60,
                )
                lease_key = keys.agent_lease(realm, "arena1", "k0")
                for _ in range(10):
                    s.put(keys.world_frame(realm, "arena1"), encode(frame))
                    s.put(lease_key, client.session.seal(lease_key, lease))
                    time.sleep(0.1)
                return result(sent=10)
        finally:
            close_session(s)

    if verb == "alive":
        # alive HOST KIND ID: is this liveliness token seen from HOST (admin certificate)?
        host, kind, ident = args
        s = session_for(lab_path, client_tls(pki, "admin"), lab.host(host).endpoint, lab.lease_ms)
        try:
            key = keys.alive(realm, AliveKind(kind), ident)
            live = {str(r.ok.key_expr) for r in s.liveliness().get(key, timeout=3) if r.ok}
            return result(alive=key in live)
        finally:
            close_session(s)

    if verb == "await":
        # await HOST KIND:ID...: wait (up to 90 s) until every token is seen from HOST.
        # The hosts' routers mesh and propagate declarations after `wart host` says it
        # runs; on a loaded machine a probe that logged in at once found no registry.
        host, *wanted = args
        s = session_for(lab_path, client_tls(pki, "admin"), lab.host(host).endpoint, lab.lease_ms)
        try:
            want = {keys.alive(realm, AliveKind(k), i) for k, i in (w.split(":") for w in wanted)}
            deadline = time.monotonic() + 90.0
            missing = set(want)
            while missing and time.monotonic() < deadline:
                got = s.liveliness().get(keys.alive_all(realm), timeout=3)
                missing = want - {str(r.ok.key_expr) for r in got if r.ok}
                if missing:
                    time.sleep(0.5)
            return result(missing=sorted(missing))
        finally:
            close_session(s)

    if verb == "follow":
        # follow HOST KIND ID SECONDS: print token events with timestamps for SECONDS.
        host, kind, ident, seconds = args[0], args[1], args[2], float(args[3])
        s = session_for(lab_path, client_tls(pki, "admin"), lab.host(host).endpoint, lab.lease_ms)
        key = keys.alive(realm, AliveKind(kind), ident)
        events: list[tuple[str, float]] = []
        started = time.monotonic()

        def on_event(sample) -> None:
            kind_ = "put" if str(sample.kind).endswith("PUT") else "delete"
            events.append((kind_, round(time.monotonic() - started, 2)))
            print("EVENT", kind_, flush=True)

        sub = s.liveliness().declare_subscriber(key, on_event, history=True)
        print("READY", flush=True)
        time.sleep(seconds)
        sub.undeclare()
        close_session(s)
        return result(events=events)

    if verb == "arena":
        # arena HOST PASSWORD_FILE WORLD: start an arena from HOST (placed by load), see
        # its world token from HOST and its agent context in the directory, stop it.
        host, password_file, world = args
        s = session_for(lab_path, client_tls(pki, "admin"), lab.host(host).endpoint, lab.lease_ms)
        try:
            with LabClient(s, realm, read_registry_key(lab), presence=False) as client:
                client.login("admin", Path(password_file).read_text().strip())
                arena = new_arena(client, map_name="foraging", robots=3, world=world, host=None)
                key = keys.alive(realm, AliveKind.WORLD, world)
                seen = any(r.ok for r in s.liveliness().get(key, timeout=3))
                kind = None
                deadline = time.monotonic() + 15
                while kind is None and time.monotonic() < deadline:
                    kinds = {c.ctx: c.kind for c in client.directory().contexts}
                    kind = kinds.get(world)
                    time.sleep(0.3)
                detail = stop_arena(client, world)
                return result(host=arena.host, seen=seen, kind=kind, stopped=detail)
        finally:
            close_session(s)

    if verb == "drive":
        # drive HOST PASSWORD_FILE: a student's process on HOST (student certificate)
        # queues the example controller on arena1 (runs in the runner's sandbox) and
        # on the emulated Khepera of real1, and drives real1's robot from here.
        from common.client.agent_client import FINAL, AgentClient
        from common.controller import load_controller

        host, password_file = args
        s = session_for(lab_path, client_tls(pki, "student"), lab.host(host).endpoint, lab.lease_ms)
        out: dict[str, object] = {}
        try:
            with LabClient(s, realm, read_registry_key(lab), presence=False) as client:
                client.login("admin", Path(password_file).read_text().strip())
                for ctx, world in (("arena1", "arena1"), ("robots", "real1")):
                    poses = Poses(s, realm, world)
                    agent = poses.rows[0]
                    agents = AgentClient(client, ctx).join()
                    try:
                        start = poses.xy(agent)
                        queued = agents.queue(
                            agent, "deploy", source=EXAMPLE.read_bytes(), filename=EXAMPLE.name
                        )
                        final = agents.wait_status(queued.request_id, FINAL, timeout=30)
                        out[f"{world}_deploy"] = final.status if final else "timeout"
                        out[f"{world}_deploy_mm"] = moved(start, poses.xy(agent))
                        if world == "real1":
                            start = poses.xy(agent)
                            driven = agents.drive(agent, load_controller(EXAMPLE))
                            out[f"{world}_remote"] = driven.status
                            out[f"{world}_remote_mm"] = moved(start, poses.xy(agent))
                        # Forged: commands sealed by this (logged-in) student while
                        # no lease of theirs is in force. The transport lets
                        # students publish commands; the engine or bridge drops them.
                        # First let the robot come to rest after its slot (the motors
                        # stop at the lease's end; the last frames may still move).
                        start = poses.xy(agent)
                        deadline = time.monotonic() + 5
                        while time.monotonic() < deadline:
                            time.sleep(0.5)
                            now = poses.xy(agent)
                            if moved(start, now) < 0.5:
                                break
                            start = now
                        key = keys.agent_cmd(realm, world, agent)
                        assert client.session is not None
                        for _ in range(30):
                            command = AgentCommand(agent=agent, speeds=(20, 20))
                            s.put(key, client.session.seal(key, command))
                            time.sleep(0.05)
                        out[f"{world}_forged_mm"] = moved(start, poses.xy(agent))
                    finally:
                        agents.leave()
                        poses.close()
                return result(**out)
        finally:
            close_session(s)

    if verb == "dir-follow":
        # dir-follow HOST PASSWORD_FILE CTX SECONDS: poll the directory, print whether
        # CTX is listed each time that changes.
        host, password_file, ctx, seconds = args[0], args[1], args[2], float(args[3])
        s = session_for(lab_path, client_tls(pki, "admin"), lab.host(host).endpoint, lab.lease_ms)
        try:
            with LabClient(s, realm, read_registry_key(lab), presence=False) as client:
                client.login("admin", Path(password_file).read_text().strip())
                print("READY", flush=True)
                listed: bool | None = None
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    now = ctx in {c.ctx for c in client.directory().contexts}
                    if now != listed:
                        listed = now
                        print("EVENT", "listed" if now else "unlisted", flush=True)
                    time.sleep(0.2)
                return result(listed=listed)
        finally:
            close_session(s)

    print(f"unknown verb {verb}", flush=True)
    return 1


if __name__ == "__main__":
    sys.exit(main())
