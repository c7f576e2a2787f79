"""`wart kube render`: a lab file's host as Kubernetes objects, valid by Kubernetes' schemas."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import kubernetes_validate
import pytest
import yaml

from services.lab.kube.manifests import KubeOptions, render
from services.lab.kube.yamlout import dump_all
from services.lab.labfile import LabFileError, load
from services.lab.pki import issue_lab
from tests.kit.procs import REPO, wart

EXAMPLE = REPO / "deploy" / "kubernetes" / "lab.toml"
SHIPPED = REPO / "deploy" / "kubernetes" / "example"
KUBERNETES = "1.30.0"  # the oldest release the manifests are for (appArmorProfile: 1.30)


@pytest.fixture(scope="module")
def lab_with_pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("kube")
    shutil.copy(EXAMPLE, tmp / "lab.toml")
    issue_lab(load(tmp / "lab.toml"), say=lambda _text: None)
    return tmp / "lab.toml"


def by_name(objects: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    return {(o["kind"], o["metadata"]["name"]): o for o in objects}


def containers(obj: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {c["name"]: c for c in obj["spec"]["template"]["spec"]["containers"]}


def test_the_shipped_manifests_are_the_example_lab_file_rendered(tmp_path: Path) -> None:
    out = tmp_path / "example"
    # All of it needs the lab's PKI, which the repository does not ship: said in words.
    done = wart("kube", "render", "--lab", str(EXAMPLE), "--name", "cluster")
    assert done.returncode == 2 and "run `wart certs lab --lab FILE` first" in done.stderr
    done = wart(
        "kube", "render", "--lab", str(EXAMPLE), "--name", "cluster", "--part", "workloads",
        "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    rendered = {p.name: p.read_text() for p in out.iterdir()}
    shipped = {p.name: p.read_text() for p in SHIPPED.iterdir()}
    assert rendered.keys() == shipped.keys()
    stale = [name for name in rendered if rendered[name] != shipped[name]]
    assert not stale, f"re-render deploy/kubernetes/example ({EXAMPLE.name} changed): {stale}"


@pytest.mark.parametrize("mode", ["kubernetes", "podman"])
def test_every_object_is_valid_for_kubernetes_and_reads_back_as_written(
    lab_with_pki: Path, mode: str
) -> None:
    objects = render(load(lab_with_pki), "cluster", KubeOptions(mode=mode)).objects
    assert len(objects) > 20
    for obj in objects:
        kubernetes_validate.validate(obj, KUBERNETES, strict=True)
    # The YAML writer: every document reads back as the object it was written from.
    assert list(yaml.safe_load_all(dump_all(objects))) == objects


def test_each_service_is_its_own_workload_with_probes_resources_and_its_state(
    lab_with_pki: Path,
) -> None:
    rendered = render(load(lab_with_pki), "cluster")
    objects = by_name(rendered.objects)
    # The router: a StatefulSet behind its Service; TLS and the access rules from Secrets.
    router = objects[("StatefulSet", "wart-router")]
    (rc,) = containers(router).values()
    assert rc["args"][:1] == ["router"] and "--no-multicast-scouting" in rc["args"]
    assert "tls/0.0.0.0:7447" in rc["args"]
    assert rc["readinessProbe"]["tcpSocket"]["port"] == 7447
    assert objects[("Service", "wart-router")]["spec"]["ports"][0]["port"] == 7447
    assert objects[("Service", "wart-router-pods")]["spec"]["clusterIP"] == "None"
    # The registry: one replica, its database on its own volume, provisioned first (then
    # the same process becomes the registry); the
    # grader writes the same database, so it is a container of the same pod.
    registry = objects[("StatefulSet", "wart-registry-registry")]
    assert registry["spec"]["replicas"] == 1
    (claim,) = registry["spec"]["volumeClaimTemplates"]
    assert claim["spec"]["accessModes"] == ["ReadWriteOnce"]
    pod = containers(registry)
    args = pod["registry"]["args"]
    assert args[:2] == ["kube", "provision"]
    assert args[args.index("--") + 1 :][:3] == ["registry", "--db", "/var/lib/wart/registry.db"]
    assert set(pod) == {"registry", "grader"}
    assert "/var/lib/wart/registry.db" in pod["grader"]["args"]
    assert pod["registry"]["readinessProbe"]["exec"]["command"] == [
        *("wart", "probe", "registry", "registry"),
    ]
    assert pod["registry"]["livenessProbe"]["exec"]["command"][-1] == "--liveness"
    # An arena: its engine and agent context in one pod, each with its own certificate.
    arena = containers(objects[("StatefulSet", "wart-arena-arena1")])
    assert set(arena) == {"engine", "agent"}
    assert arena["engine"]["args"][:3] == ["engine", "--map", "/opt/wart/maps/foraging.json"]
    assert arena["agent"]["readinessProbe"]["exec"]["command"][2:] == ["context", "arena1"]
    mounts = {m["mountPath"]: m["name"] for m in arena["agent"]["volumeMounts"]}
    assert mounts["/etc/wart/tls"] == "tls-agent"
    env = {e["name"]: e for e in arena["engine"]["env"]}
    assert env["WART_CONNECT"]["value"] == "tls/wart-router:7447"
    assert env["WART_ZENOH_CONFIG"]["value"] == "/etc/wart/zenoh/engine.json5"
    assert env["WART_NO_MULTICAST"]["value"] == "1"
    assert env["WART_REGISTRY_KEY"]["valueFrom"]["configMapKeyRef"]["name"] == "wart-lab"
    # A chat room keeps its history on a volume; so does the viewer keep its pages' tabs
    # (the next pod of an upgrade opens them again); it has a Service and an Ingress.
    assert objects[("StatefulSet", "wart-chat-lobby")]["spec"]["volumeClaimTemplates"]
    viewer = objects[("StatefulSet", "wart-viewer-viewer")]
    assert viewer["spec"]["volumeClaimTemplates"][0]["metadata"]["name"] == "state"
    args = containers(viewer)["viewer"]["args"]
    assert "0.0.0.0" in args and args[args.index("--data-dir") + 1].startswith("/var/lib/wart")
    (rule,) = objects[("Ingress", "wart-viewer-viewer")]["spec"]["rules"]
    assert rule["host"] == "lab.example.org"  # the host's public name, not the router's
    # The routers' rules do not let a camera watch tokens: its probe could only fail.
    camera = containers(objects[("Deployment", "wart-camera-arena1")])["camera"]
    assert "readinessProbe" not in camera and "livenessProbe" not in camera
    runner_pod = objects[("Deployment", "wart-runner-runner")]
    runner = containers(runner_pod)["runner"]
    # Each sandbox mounts a /proc of its own: an unmasked one, in a user namespace.
    assert runner["securityContext"]["seccompProfile"]["type"] == "Unconfined"
    assert runner["securityContext"]["procMount"] == "Unmasked"
    assert runner_pod["spec"]["template"]["spec"]["hostUsers"] is False
    assert "privileged" not in runner["securityContext"]
    # The runner scaled on the grader's queue: its pods named apart, its replicas the host's.
    grading_pod = objects[("Deployment", "wart-runner-grading")]
    grading = containers(grading_pod)["runner"]
    assert "replicas" not in grading_pod["spec"] and runner_pod["spec"]["replicas"] == 1
    assert grading["args"][:3] == ["runner", "--name", "$(POD_NAME)"]
    assert grading["env"][0]["valueFrom"]["fieldRef"]["fieldPath"] == "metadata.name"
    probe = grading["readinessProbe"]["exec"]["command"]
    assert probe == ["sh", "-c", 'exec wart probe runner "$POD_NAME"']
    *_, scale = objects[("Role", "wart-host")]["rules"]
    assert scale == {
        "apiGroups": ["apps"],
        "resources": ["deployments/scale"],
        "resourceNames": ["wart-runner-grading"],
        "verbs": ["get", "patch"],
    }
    # Every container: the image's user, requests and limits.
    for obj in rendered.objects:
        if obj["kind"] in ("StatefulSet", "Deployment"):
            assert obj["spec"]["template"]["spec"]["securityContext"]["runAsNonRoot"] is True
            for c in containers(obj).values():
                assert set(c["resources"]) == {"requests", "limits"}, obj["metadata"]["name"]
    # The Secrets carry the lab's PKI: a role's certificate, the identities, the key.
    tls = objects[("Secret", "wart-tls-engine")]["stringData"]
    assert tls["cert.pem"].startswith("-----BEGIN CERTIFICATE-----")
    identities = objects[("Secret", "wart-identities")]["stringData"]
    assert {"chat-lobby.key", "agent-cluster.key", "grader-grader.key"} <= set(identities)
    assert len(objects[("Secret", "wart-registry-key")]["stringData"]["registry.key"]) == 64


def test_podman_gets_only_what_it_plays_on_the_host_network(lab_with_pki: Path) -> None:
    objects = render(load(lab_with_pki), "cluster", KubeOptions(mode="podman")).objects
    # Secrets as ConfigMaps: podman 4.3 mounts a Secret's data still encoded.
    assert {o["kind"] for o in objects} == {"Deployment", "PersistentVolumeClaim", "ConfigMap"}
    for obj in objects:
        if obj["kind"] == "Deployment":
            pod = obj["spec"]["template"]["spec"]
            assert pod["hostNetwork"] is True
            assert obj["spec"]["strategy"]["type"] == "Recreate"
            for c in pod["containers"]:
                env = {e["name"]: e.get("value") for e in c["env"]}
                assert env.get("WART_CONNECT", "tls/127.0.0.1:7447") == "tls/127.0.0.1:7447"
                assert "ports" not in c
    claims = {o["metadata"]["name"] for o in objects if o["kind"] == "PersistentVolumeClaim"}
    assert "wart-registry-registry-state" in claims
    # podman 4.3 ignores procMount: the runner's container is privileged instead.
    (runner,) = (o for o in objects if o["metadata"]["name"] == "wart-runner-runner")
    assert runner["spec"]["template"]["spec"]["containers"][0]["securityContext"] == {
        "privileged": True
    }


def test_a_router_certificate_without_the_service_name_is_refused(tmp_path: Path) -> None:
    text = EXAMPLE.read_text().replace('names = ["wart-router", ', "names = [")
    (tmp_path / "lab.toml").write_text(text)
    with pytest.raises(LabFileError, match=r"hosts\[0\].names must list 'wart-router'"):
        render(load(tmp_path / "lab.toml"), "cluster")


@pytest.mark.parametrize(
    ("flag", "value", "said"),
    [
        ("--namespace", "Lab_1", "namespace 'Lab_1': expected a DNS label"),
        ("--state-size", "lots", "state size 'lots': expected a quantity"),
        ("--image", "wart image", "image 'wart image': expected an image reference"),
    ],
)
def test_a_wrong_option_is_refused_with_what_was_expected(flag: str, value: str, said: str) -> None:
    done = wart(
        "kube", "render", "--lab", str(EXAMPLE), "--name", "cluster", "--part", "workloads",
        flag, value,
    )  # fmt: skip
    assert done.returncode == 2 and said in done.stderr and not done.stdout
