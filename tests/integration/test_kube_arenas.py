"""Arenas on request in a cluster: ``wart arena new`` makes a StatefulSet through the API;
runners scaled on the grader's queue depth.

A real lab (router, registry), ``wart kube host`` as its host, and in place of
a cluster a small HTTP server speaking the endpoints it uses (create and
delete a StatefulSet or a ConfigMap; read and patch a Deployment's scale).
When a StatefulSet is created, the test plays the kubelet: it declares the
arena's liveliness tokens, as its pod would once serving; when it is deleted,
it takes them away.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl

import pytest
import zenoh

from common import keys
from common.client.grader_client import GraderClient
from common.client.host_client import host_loads
from common.keys import AliveKind
from common.lab_errors import LabError
from services.commands.arena import format_loads, new_arena, stop_arena
from tests.kit.courses import assignment_toml, import_roster
from tests.kit.json_http import send_json
from tests.kit.lab import ProcessLab, make_lab
from tests.kit.procs import Proc, Procs, Router, wait_alive, wart
from tests.kit.waits import wait_for

NS = "labns"
WORKS = Path(__file__).parent / "grading" / "works.py"  # reaches the goal
LAB = """
realm = "{realm}"
[security]
pki = "pki"
[limits]
max_robots_per_arena = 20
[[hosts]]
name = "cluster"
address = "203.0.113.10"
names = ["wart-router"]
arenas = true
[[hosts.services]]
kind = "registry"   # the kit's, started by the test
"""


class FakeCluster:
    """The API endpoints `wart kube host` uses, each request kept for the test to read."""

    def __init__(self, session: zenoh.Session, realm: str) -> None:
        self.requests: list[tuple[str, str, dict[str, Any]]] = []  # method, path, body/query
        self.objects: dict[str, dict[str, Any]] = {}
        self.replicas: dict[str, int] = {}  # a Deployment's, as its scale says
        self.patches: list[tuple[str, str, int]] = []  # name, content type, replicas
        self.tokens: dict[str, list[zenoh.LivelinessToken]] = {}
        cluster = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: object) -> None:
                pass

            def scale(self, name: str) -> dict[str, Any]:
                n = cluster.replicas[name]
                meta = {"name": name, "namespace": NS}
                spec = {"replicas": n}
                return {"kind": "Scale", "apiVersion": "autoscaling/v1", "metadata": meta,
                        "spec": spec, "status": {"replicas": n}}  # fmt: skip

            def scale_of(self) -> str | None:
                """The Deployment whose scale the path names (None: another path)."""
                head = f"/apis/apps/v1/namespaces/{NS}/deployments/"
                name = self.path.removeprefix(head).removesuffix("/scale")
                if not self.path.startswith(head) or name not in cluster.replicas:
                    return None
                return name

            def do_GET(self) -> None:
                name = self.scale_of()
                if name is None:
                    send_json(self, 404, {"kind": "Status", "status": "Failure", "code": 404})
                    return
                send_json(self, 200, self.scale(name))

            def do_PATCH(self) -> None:
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                name = self.scale_of()
                if name is None:
                    send_json(self, 404, {"kind": "Status", "status": "Failure", "code": 404})
                    return
                kind = self.headers["Content-Type"]
                cluster.patches.append((name, kind, body["spec"]["replicas"]))
                if kind != "application/merge-patch+json":  # what the body is
                    send_json(self, 415, {"kind": "Status", "status": "Failure", "code": 415})
                    return
                cluster.replicas[name] = body["spec"]["replicas"]
                send_json(self, 200, self.scale(name))

            def do_POST(self) -> None:
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                cluster.requests.append(("POST", self.path, body))
                cluster.objects[f"{self.path}/{body['metadata']['name']}"] = body
                if self.path.endswith("/statefulsets"):  # the pod comes up and serves
                    world = body["metadata"]["labels"]["wart.lab/service"]
                    cluster.tokens[world] = [
                        session.liveliness().declare_token(keys.alive(realm, kind, world))
                        for kind in (AliveKind.WORLD, AliveKind.CONTEXT)
                    ]
                send_json(self, 201, body)

            def do_DELETE(self) -> None:
                path, _, query = self.path.partition("?")
                cluster.requests.append(("DELETE", path, dict(parse_qsl(query))))
                if cluster.objects.pop(path, None) is None:
                    send_json(self, 404, {"kind": "Status", "status": "Failure", "code": 404})
                    return
                if "/statefulsets/" in path:
                    world = path.rsplit("/", 1)[1].removeprefix("wart-arena-")
                    for token in cluster.tokens.pop(world, []):
                        token.undeclare()
                send_json(self, 200, {"kind": "Status", "status": "Success"})

        self.handler = Handler
        self.port = 0
        self.open()

    def open(self) -> None:
        """Serve (again, on the same port: the API server back)."""
        self.server = ThreadingHTTPServer(("127.0.0.1", self.port), self.handler)
        self.port = self.server.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        if self.server.socket.fileno() != -1:  # not closed already
            self.server.shutdown()
            self.server.server_close()


def start_host(
    lab: ProcessLab, procs: Procs, tmp: Path, cluster: FakeCluster, text: str, *extra: str
) -> Proc:
    """``wart kube host`` for the lab file ``text``, its API the fake cluster's."""
    (tmp / "lab.toml").write_text(text.format(realm=lab.realm))
    host = procs.start(
        "kube-host",
        [
            *("kube", "host", "--lab", str(tmp / "lab.toml"), "--name", "cluster"),
            *("--image", "registry.example.org/wart:1.0", "--namespace", NS),
            *("--api-server", cluster.url, "--state-dir", str(tmp / "host")),
            *extra,
            *lab.net_args(),
        ],
    )
    # Importing the kubernetes client is slow on a busy machine (measured: over 30 s).
    wait_alive(lab.router.options(), keys.alive(lab.realm, AliveKind.HOST, "cluster"), host, 90)
    return host


@pytest.fixture
def cluster_lab(
    router: Router, procs: Procs, tmp_path: Path
) -> Iterator[tuple[ProcessLab, FakeCluster]]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    session = lab.zsession()
    cluster = FakeCluster(session, lab.realm)
    start_host(lab, procs, tmp_path, cluster, LAB)
    try:
        yield lab, cluster
    finally:
        cluster.close()
        session.close()


def test_an_arena_asked_for_is_a_statefulset_made_through_the_api_and_deleted_on_stop(
    cluster_lab: tuple[ProcessLab, FakeCluster],
) -> None:
    lab, cluster = cluster_lab
    with lab.client("ida") as ida:  # an instructor: the host permission
        arena = new_arena(ida, map_name="foraging", robots=3, world="a2", host=None)
        assert (arena.host, arena.world, arena.state, arena.owner) == (
            "cluster",
            "a2",
            "running",
            "ida",
        )
        # Its map was written for 3 robots: a ConfigMap, then the StatefulSet that mounts it.
        (post_map, post_set) = cluster.requests
        assert post_map[:2] == ("POST", f"/api/v1/namespaces/{NS}/configmaps")
        config = post_map[2]
        assert config is not None and config["metadata"]["name"] == "wart-arena-a2-map"
        (group,) = json.loads(config["data"]["a2.json"])["agent_groups"]
        assert group["count"] == 3
        assert post_set[:2] == ("POST", f"/apis/apps/v1/namespaces/{NS}/statefulsets")
        sts = post_set[2]
        assert sts is not None
        assert sts["metadata"]["name"] == "wart-arena-a2"
        assert sts["metadata"]["namespace"] == NS
        assert sts["metadata"]["labels"]["wart.lab/on-request"] == "true"
        assert sts["metadata"]["annotations"]["wart.lab/owner"] == "ida"
        spec = sts["spec"]
        assert spec["replicas"] == 1
        assert spec["persistentVolumeClaimRetentionPolicy"]["whenDeleted"] == "Delete"
        pod = spec["template"]["spec"]
        assert pod["securityContext"]["runAsNonRoot"] is True
        engine, agent = pod["containers"]
        assert engine["image"] == agent["image"] == "registry.example.org/wart:1.0"
        args = engine["args"]
        assert args[:3] == ["engine", "--map", "/etc/wart/arena-map/a2.json"]
        assert args[args.index("--world") + 1] == "a2"
        assert {"name": "map", "configMap": {"name": "wart-arena-a2-map"}} in pod["volumes"]
        env = {e["name"]: e.get("value") for e in engine["env"]}
        assert env["WART_CONNECT"] == "tls/wart-router:7447"
        assert env["WART_REALM"] == lab.realm
        assert agent["args"][:6] == ["context", "agent", "--name", "a2", "--world", "a2"]
        assert agent["args"][agent["args"].index("--owner") + 1] == "ida"
        assert agent["args"][agent["args"].index("--user") + 1] == "agent-cluster"
        assert agent["readinessProbe"]["exec"]["command"] == ["wart", "probe", "context", "a2"]
        assert engine["resources"]["limits"]["memory"] == "1Gi"
        # A name taken is refused before anything is asked of the cluster.
        with pytest.raises(LabError, match="taken"):
            new_arena(ida, map_name="foraging", robots=None, world="a2", host=None)
        assert len(cluster.requests) == 2
        # Closed: both objects deleted, the pod's tokens gone with them.
        said = stop_arena(ida, "a2")
        assert "a2 stopped on cluster" in said
        deletes = [(method, path) for method, path, _ in cluster.requests[2:]]
        assert deletes == [
            ("DELETE", f"/apis/apps/v1/namespaces/{NS}/statefulsets/wart-arena-a2"),
            ("DELETE", f"/api/v1/namespaces/{NS}/configmaps/wart-arena-a2-map"),
        ]
        assert cluster.requests[2][2] == {"propagationPolicy": "Foreground"}
        assert not cluster.tokens and not cluster.objects
    with lab.client("alice") as alice, pytest.raises(LabError, match="host"):
        new_arena(alice, map_name="foraging", robots=None, world="a3", host=None)  # a student
    assert len(cluster.requests) == 4
    # No API server: the request is refused in words, and the host keeps serving.
    cluster.close()
    with lab.client("ida") as ida:
        with pytest.raises(LabError, match="the Kubernetes API did not answer"):
            new_arena(ida, map_name="foraging", robots=None, world="a4", host=None)
        assert "cluster" in format_loads(host_loads(ida.z, ida.realm))


SCALED = (
    LAB
    + """
[[hosts.services]]
kind = "runner"
name = "grading"
min_replicas = 1
max_replicas = 3
per_replica = 1
cooldown_s = 2
"""
)
RUNNERS = "wart-runner-grading"


def test_runners_follow_the_graders_queue_up_to_the_cap_and_back_after_the_cool_down(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    import_roster(lab)
    (tmp_path / "a.toml").write_text(assignment_toml("reach", episodes="1", quota="10"))
    done = wart("course", "--db", str(lab.db_path), "assignment", "add", str(tmp_path / "a.toml"))
    assert done.returncode == 0, done.stderr
    # No runner yet: each submission waits for one (the pods the scale brings).
    lab.start_grader("--runner-wait", "120")
    session = lab.zsession()
    cluster = FakeCluster(session, lab.realm)
    cluster.replicas[RUNNERS] = 1
    host = start_host(lab, procs, tmp_path, cluster, SCALED, "--scale-period", "0.3")
    try:
        with lab.client("alice") as alice:
            grader = GraderClient(alice)
            subs = [
                grader.submit("reach", WORKS.read_bytes(), "works.py").submission for _ in range(4)
            ]
            # 2 graded (waiting for a runner) and 2 queued: 4 wanted, 3 the cap.
            wait_for(lambda: cluster.replicas[RUNNERS] == 3, 20, "the runners scaled up")
            assert all(kind == "application/merge-patch+json" for _, kind, _ in cluster.patches)
            assert all(name == RUNNERS and n <= 3 for name, _, n in cluster.patches)
            # The API goes down; the runner the scale asked for comes up anyway (a pod).
            cluster.close()
            lab.start_runner("grading-5d8c7b9f6-x2x4z")
            for sub in subs:  # the lab grades with what it has
                assert grader.wait_graded("reach", sub, 60).status == "graded"
            said = "the Kubernetes API did not answer"
            wait_for(lambda: said in host.output(), 20, "the host saying the API is down")
            assert "grading goes on with them" in host.output()
            assert cluster.replicas[RUNNERS] == 3
            # The API back: the queue has been empty for longer than the cool-down.
            cluster.open()
            wait_for(lambda: cluster.replicas[RUNNERS] == 1, 20, "the runners scaled down")
            assert "the Kubernetes API answers again" in host.output()
            assert cluster.patches[-1] == (RUNNERS, "application/merge-patch+json", 1)
    finally:
        cluster.close()
        session.close()
