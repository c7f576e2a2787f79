"""Arenas on request in a cluster: ``wart arena new`` makes a StatefulSet through the API.

A real lab (router, registry), ``wart kube host`` as its host, and in place of
a cluster a small HTTP server speaking the four endpoints it uses (create and
delete a StatefulSet or a ConfigMap). When a StatefulSet is created, the test
plays the kubelet: it declares the arena's liveliness tokens, as its pod
would once serving; when it is deleted, it takes them away.
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
from common.client.host_client import host_loads
from common.keys import AliveKind
from common.lab_errors import LabError
from services.commands.arena import format_loads, new_arena, stop_arena
from tests.kit.lab import ProcessLab, Procs, Router, make_lab

pytestmark = pytest.mark.integration

NS = "labns"
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
        self.tokens: dict[str, list[zenoh.LivelinessToken]] = {}
        cluster = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: object) -> None:
                pass

            def reply(self, status: int, body: dict[str, Any]) -> None:
                data = json.dumps(body).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

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
                self.reply(201, body)

            def do_DELETE(self) -> None:
                path, _, query = self.path.partition("?")
                cluster.requests.append(("DELETE", path, dict(parse_qsl(query))))
                if cluster.objects.pop(path, None) is None:
                    self.reply(404, {"kind": "Status", "status": "Failure", "code": 404})
                    return
                if "/statefulsets/" in path:
                    world = path.rsplit("/", 1)[1].removeprefix("wart-arena-")
                    for token in cluster.tokens.pop(world, []):
                        token.undeclare()
                self.reply(200, {"kind": "Status", "status": "Success"})

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        if self.server.socket.fileno() != -1:  # not closed already
            self.server.shutdown()
            self.server.server_close()


@pytest.fixture
def cluster_lab(
    router: Router, procs: Procs, tmp_path: Path
) -> Iterator[tuple[ProcessLab, FakeCluster]]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    session = lab.zsession()
    cluster = FakeCluster(session, lab.realm)
    (tmp_path / "lab.toml").write_text(LAB.format(realm=lab.realm))
    host = procs.start(
        "kube-host",
        [
            *("kube", "host", "--lab", str(tmp_path / "lab.toml"), "--name", "cluster"),
            *("--image", "registry.example.org/wart:1.0", "--namespace", NS),
            *("--api-server", cluster.url, "--state-dir", str(tmp_path / "host")),
            *lab.net_args(),
        ],
    )
    lab.wait_alive(AliveKind.HOST, "cluster", host)
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
