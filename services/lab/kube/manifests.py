"""One host of a lab file as Kubernetes objects: the cluster plays that host.

Why a renderer and not a Helm chart or a kustomize base: the manifests are a
function of the lab file (which services, which accounts and certificates,
the routers' access rules, the registry's key), and every command line is
written once, in services/lab/wiring.py, for ``wart host`` and ``wart up``
alike; a template would write them a second time and drift. Neither helm nor
kustomize comes from Debian's or PyPI's packages, and the output is plain
YAML that kustomize overlays as it is (``wart kube render --out DIR`` writes
a kustomization.yaml beside it).

What each service becomes (docs/DEPLOY.md, "On Kubernetes"):

- the host's router: a StatefulSet of one, its Service (clients connect to
  ``tls/wart-router:PORT``: the host's ``names`` must list ``wart-router``,
  since clients check the router's certificate name), TLS from a Secret, the
  access rules in its Zenoh config (a Secret too: it names the key files);
- registry: a StatefulSet of one with a volume for its SQLite database,
  provisioned first in its container (admin, service accounts); the grader, who
  writes the same database, is a second container of that pod (one writer's
  volume, never shared across pods);
- chat rooms, agent contexts, arenas (engine + agent context, one pod), the
  LTI tool: StatefulSets of one with a volume for their history and queues;
- runners and cameras: Deployments (nothing of theirs outlives a pod);
- a viewer: a StatefulSet of one (its pages' tabs outlive an upgrade), a Service and an
  Ingress example.

Every container has a readiness and a startup probe ``wart probe KIND ID``
(its liveliness token is in the lab) and a liveness probe ``--liveness``
(its token is gone while the router answers). ``mode="podman"``: the same
pods as Deployments on the host's network, without Services, Ingresses and
StatefulSets, which ``podman kube play`` does not run.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath
from typing import Any

from common import keys
from common.keys import AliveKind
from services.lab import wiring
from services.lab.kube.objects import (
    MODES,
    PARTS,
    STATE,
    KubeOptions,
    Objects,
    object_name,
)
from services.lab.lab_maps import SHIPPED_MAPS
from services.lab.labfile import HostEntry, LabFile, LabFileError, ServiceEntry
from services.lab.pki import ACCOUNTS, REGISTRY_PUB, host_roles, identity_path, registry_key_path
from services.lab.supervisor import ChildSpec
from services.lab.wiring import Wiring
from services.lab.zsecurity import ROLE_GRANTS, TlsFiles, acl_config, host_tls, zenoh_security

__all__ = ["MODES", "PARTS", "KubeOptions", "Rendered", "Renderer", "render"]

ROUTER = "wart-router"
TLS = PurePosixPath("/etc/wart/tls")
ZENOH = PurePosixPath("/etc/wart/zenoh")
IDENTITIES = PurePosixPath("/etc/wart/identities")
REGISTRY_KEY = PurePosixPath("/etc/wart/registry")
LAB_FILES = PurePosixPath("/etc/wart/lab")
RBAC = "rbac.authorization.k8s.io"
MAP_CONFIG = PurePosixPath("/etc/wart/arena-map")  # an arena's own map (arenas.py)
IMAGE_MAPS = PurePosixPath("/opt/wart/maps")  # the image's shipped maps (deploy/container)

# Requests and limits per process kind, from `wart up` measured on the project's 2-core
# machine (docs/DEPLOY.md, "On Kubernetes": each process's resident memory and CPU over
# 30 s, two minutes after the start, its arenas' robots ticking, nobody logged in).
# Requests: that with some room; limits: room for a class (memory) and bursts (CPU).
RESOURCES: dict[str, tuple[str, str, str, str]] = {
    # kind: (cpu request, memory request, cpu limit, memory limit); idle RSS, CPU measured
    "router": ("50m", "128Mi", "1", "512Mi"),  # 119 MiB, 1.7 % of a core
    "registry": ("20m", "96Mi", "1", "384Mi"),  # 56 MiB, 0.2 %
    "grader": ("20m", "96Mi", "2", "1Gi"),  # 62 MiB, 0.1 %; episodes are simulated in it
    "chat": ("20m", "96Mi", "500m", "256Mi"),  # 57 MiB, 0.1 %
    "agent": ("20m", "128Mi", "500m", "384Mi"),  # 77-96 MiB, 1.1 %
    "engine": ("100m", "160Mi", "2", "1Gi"),  # 98 MiB, 3.1 % at 10 robots
    "runner": ("20m", "96Mi", "2", "2Gi"),  # 62 MiB idle; each sandbox adds its controller's
    "viewer": ("50m", "128Mi", "2", "1Gi"),  # 93 MiB, 0.3 % with no page open
    "camera": ("250m", "192Mi", "1", "512Mi"),  # 118 MiB, 17.5 % (a synthetic camera)
    "lti": ("20m", "96Mi", "500m", "256Mi"),
    "host": ("20m", "128Mi", "500m", "384Mi"),  # not measured: an agent context's figures
}


@dataclass
class Rendered:
    """The objects in apply order, and what the lab file has that they leave out."""

    objects: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)


class Renderer:
    """The objects of one lab-file host; one instance per rendering."""

    def __init__(self, lab: LabFile, host: HostEntry, options: KubeOptions) -> None:
        self.k = Objects(options)
        self.lab, self.host, self.o = lab, host, options
        self.podman = self.k.podman
        if self.podman:
            self.endpoint = host.local_endpoint  # the pods share the host's network
        else:
            if ROUTER not in (host.address, *host.names):
                index = lab.hosts.index(host)
                raise LabFileError(
                    f"hosts[{index}].names must list {ROUTER!r}: pods reach the router "
                    "through that Service, and check that its certificate names it"
                )
            self.endpoint = f"tls/{ROUTER}:{host.port}"
        self.wiring = Wiring(
            realm=lab.realm,
            host=host.name,
            state_dir=Path(str(STATE)),
            net_args=lambda role: [],  # in the environment (env_for): the probes share it
            identity=lambda account: Path(str(IDENTITIES / f"{account}.key")),
            registry_key_file=Path(str(REGISTRY_KEY / "registry.key")),
            map_dirs=(lab.maps_dir, SHIPPED_MAPS),
            runner=lab.runner_for(host.name),
            arena=lab.arena,
            http_host="0.0.0.0",
            lab_address=f"{host.address}:{host.port}/{lab.realm}",
        )

    # --- shared parts ------------------------------------------------------------------

    def env_for(self, role: str) -> list[dict[str, Any]]:
        """A process's network settings: its role's TLS config and the router (as flags
        would give them: common/zconfig.py reads these for every command)."""
        return [
            {"name": "WART_REALM", "value": self.lab.realm},
            {"name": "WART_CONNECT", "value": self.endpoint},
            {"name": "WART_ZENOH_CONFIG", "value": str(ZENOH / f"{role}.json5")},
            {
                "name": "WART_REGISTRY_KEY",
                "valueFrom": {"configMapKeyRef": {"name": "wart-lab", "key": REGISTRY_PUB}},
            },
            {"name": "WART_NO_MULTICAST", "value": "1"},
        ]

    def zenoh_config(self, role: str) -> dict[str, Any]:
        tls = TlsFiles(
            Path(str(TLS / "ca.pem")), Path(str(TLS / "cert.pem")), Path(str(TLS / "key.pem"))
        )
        acl = None
        if role == "router" and self.lab.security.acl:
            names = {"student": self.lab.security.student_names}
            acl = acl_config(self.lab.realm, {**names, "admin": self.lab.security.admin_names})
        conf = zenoh_security(tls, lease_ms=self.lab.lease_ms, acl=acl, check_files=False)
        conf["metadata"] = {"name": self.host.name, "role": role, "realm": self.lab.realm}
        return conf

    def probes(self, spec: ChildSpec, role: str) -> dict[str, Any]:
        """``wart probe`` on the service's token, asked with the pod's certificate: none for
        a role the routers do not let watch tokens (a camera), whose probe would fail."""
        parsed = keys.parse_alive(self.lab.realm, spec.alive_key or "")
        if parsed is None or not any(g.verb == "watch" for g in ROLE_GRANTS.get(role, ())):
            return {}
        kind, ident = parsed
        probe = ["wart", "probe", kind.value, ident]
        every = {"timeoutSeconds": 10, "periodSeconds": 10}
        return {
            # An engine's first start may compile its kernels (a node whose CPU differs
            # from the build machine's): up to 5 minutes before it serves.
            "startupProbe": {"exec": {"command": probe}, **every, "failureThreshold": 30},
            "readinessProbe": {"exec": {"command": probe}, **every, "failureThreshold": 2},
            "livenessProbe": {
                "exec": {"command": [*probe, "--liveness"]},
                **every,
                "periodSeconds": 30,
                "failureThreshold": 3,
            },
        }

    def container(self, name: str, role: str, spec: ChildSpec, kind: str) -> dict[str, Any]:
        cpu, memory, cpu_max, memory_max = RESOURCES[kind]
        c: dict[str, Any] = {
            "name": name,
            "image": self.o.image,
            "args": [self.pod_path(a) for a in spec.argv],
            "env": self.env_for(role),
            "resources": {
                "requests": {"cpu": cpu, "memory": memory},
                "limits": {"cpu": cpu_max, "memory": memory_max},
            },
            "volumeMounts": [
                {"name": "tls", "mountPath": str(TLS), "readOnly": True},
                {"name": "zenoh", "mountPath": str(ZENOH), "readOnly": True},
            ],
            **self.probes(spec, role),
        }
        accounts = [spec.argv[i + 1] for i, a in enumerate(spec.argv) if a == "--user"]
        if accounts:
            c["volumeMounts"].append(
                {"name": "identities", "mountPath": str(IDENTITIES), "readOnly": True}
            )
        return c

    def pod_path(self, arg: str) -> str:
        """A map resolved on this machine, as the pod sees it: the image's shipped maps."""
        path = Path(arg)
        return str(IMAGE_MAPS / path.name) if self.is_shipped(path) else arg

    @staticmethod
    def is_shipped(path: Path) -> bool:
        """A map of the repository's maps/ (in the image: /opt/wart/maps)."""
        return path.suffix == ".json" and path.parent == SHIPPED_MAPS

    def volumes(self, role: str, accounts: list[str]) -> list[dict[str, Any]]:
        vols = [
            self.k.secret_volume("tls", f"wart-tls-{role}"),
            self.k.secret_volume("zenoh", "wart-zenoh"),
        ]
        if accounts:
            files = [f"{account}.key" for account in accounts]
            vols.append(self.k.secret_volume("identities", "wart-identities", files))
        return vols

    # --- the lab's services ------------------------------------------------------------

    def router(self) -> list[dict[str, Any]]:
        host = self.host
        spec = wiring.router_spec(
            self.lab.realm,
            host.name,
            [f"tls/0.0.0.0:{host.port}"],
            connect=[self.lab.host(other).endpoint for other in host.connect],
            config=Path(str(ZENOH / "router.json5")),
        )
        c = self.container("router", "router", spec, "router")
        c["env"] = []  # the router's flags are its command line
        # The router's own port: it serves when it listens (its token is its own).
        tcp = {"tcpSocket": {"port": host.port}, "periodSeconds": 10}
        for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
            c.pop(probe, None)
        c["readinessProbe"] = tcp
        c["livenessProbe"] = {**tcp, "failureThreshold": 3}
        c["ports"] = [{"name": "zenoh-tls", "containerPort": host.port}]
        volumes = self.volumes("router", [])
        # A StatefulSet (stable names for a mesh of several), but nothing of its own to keep.
        objects = self.k.workload("router", host.name, [c], volumes, stateful=not self.podman)
        if self.podman:
            return objects
        objects[0]["metadata"]["name"] = ROUTER
        objects[0]["spec"]["serviceName"] = f"{ROUTER}-pods"
        del objects[0]["spec"]["volumeClaimTemplates"]  # the router keeps nothing
        objects[0]["spec"]["template"]["spec"]["volumes"].append({"name": "state", "emptyDir": {}})
        labels = objects[0]["metadata"]["labels"]
        ident = labels["wart.lab/service"]
        main = self.k.service(ROUTER, "router", ident, host.port, type=self.o.router_service_type)
        pods = self.k.service(f"{ROUTER}-pods", "router", ident, host.port, clusterIP="None")
        return [main, pods, *objects]

    def registry(self, svc: ServiceEntry, grader: ServiceEntry | None) -> list[dict[str, Any]]:
        w = self.wiring
        spec = wiring.service_specs(w, svc)[0]
        # Its database first (admin, the lab's service accounts), then the registry in the
        # same process: an init container would do, but podman 4.3 restarts init
        # containers under the pod's restart policy and then fails to remove them.
        provision = [
            *("kube", "provision", "--state-dir", str(STATE)),
            *("--registry-key-file", str(REGISTRY_KEY / "registry.key")),
            *("--accounts", str(LAB_FILES / ACCOUNTS)),
            *("--registry-pub-file", str(LAB_FILES / REGISTRY_PUB), "--"),
        ]
        spec = replace(spec, argv=[*provision, *spec.argv])
        containers = [self.container("registry", "registry", spec, "registry")]
        containers[0]["volumeMounts"] += [
            {"name": "registry-key", "mountPath": str(REGISTRY_KEY), "readOnly": True},
            {"name": "lab", "mountPath": str(LAB_FILES), "readOnly": True},
        ]
        accounts: list[str] = []
        if grader is not None:
            g = wiring.service_specs(w, grader)[0]
            containers.append(self.container("grader", "grader", g, "grader"))
            accounts.append(wiring.service_account("grader", grader.ident))
        volumes = self.volumes("registry", accounts)
        volumes.append(self.k.secret_volume("registry-key", "wart-registry-key"))
        volumes.append({"name": "lab", "configMap": {"name": "wart-lab"}})
        # The grader's certificate is its own role's: a second TLS volume for its container.
        if grader is not None:
            volumes.append(self.k.secret_volume("tls-grader", "wart-tls-grader"))
            containers[1]["volumeMounts"][0]["name"] = "tls-grader"
        return self.k.workload("registry", "registry", containers, volumes, stateful=True)

    def one_pod(self, svc: ServiceEntry) -> list[dict[str, Any]]:
        """A chat room, an agent context, a runner, a camera, the LTI tool: one container."""
        spec = wiring.service_specs(self.wiring, svc)[0]
        role = "chat" if svc.kind == "chat" else svc.kind
        c = self.container(svc.kind, role, spec, svc.kind)
        accounts = [spec.argv[i + 1] for i, a in enumerate(spec.argv) if a == "--user"]
        volumes = self.volumes(role, accounts)
        stateful = svc.kind in ("chat", "agent", "lti")
        if svc.kind == "runner":
            # bubblewrap makes user, PID and mount namespaces for each sandbox and mounts
            # a /proc in it: the container runtime's default seccomp and AppArmor
            # profiles forbid the first, its masked /proc the second (an unmasked /proc
            # needs the pod in a user namespace of its own). The trade-off
            # (docs/DEPLOY.md): the runner's container is unconfined by them; each
            # controller still runs under the sandbox's own seccomp filter.
            c["securityContext"] = {
                "seccompProfile": {"type": "Unconfined"},
                "appArmorProfile": {"type": "Unconfined"},
                "procMount": "Unmasked",
                "allowPrivilegeEscalation": False,
            }
            if self.podman:
                # podman kube play 4.3 ignores procMount, and without it no sandbox
                # can mount its /proc; privileged is the one setting it honours that
                # unmasks it. On the lab's own host, not on a shared cluster.
                c["securityContext"] = {"privileged": True}
        if svc.scale is not None and not self.podman:
            self.named_by_pod(svc, c)
        objects = self.k.workload(svc.kind, svc.ident, [c], volumes, stateful=stateful)
        if svc.kind == "runner" and not self.podman:
            objects[-1]["spec"]["template"]["spec"]["hostUsers"] = False
        if svc.scale is not None and not self.podman:
            # The host pod sets the replicas (runner_scale.py): an apply of these
            # objects again leaves them as they are (a new Deployment starts with one).
            del objects[-1]["spec"]["replicas"]
        return objects

    def named_by_pod(self, svc: ServiceEntry, c: dict[str, Any]) -> None:
        """A scaled runner's pods each serve under their pod's name (the grader takes any
        runner alive; one name for all would be one queryable and one token)."""
        name = object_name(svc.kind, svc.ident)
        if len(name) > 47:  # its pods' names: NAME-HASH(10)-XXXXX, a name of the lab: <= 64
            raise LabFileError(
                f"runner {svc.ident!r}: the name {name!r} is too long for a scaled runner "
                "(47 characters at most)"
            )
        args = c["args"]
        args[args.index("--name") + 1] = "$(POD_NAME)"  # Kubernetes expands it from env
        c["env"].insert(
            0, {"name": "POD_NAME", "valueFrom": {"fieldRef": {"fieldPath": "metadata.name"}}}
        )
        for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
            if probe in c:  # an exec probe's command is not expanded: a shell does it
                command = c[probe]["exec"]["command"]
                said = " ".join([*command[:3], '"$POD_NAME"', *command[4:]])
                c[probe]["exec"]["command"] = ["sh", "-c", f"exec {said}"]

    def arena(self, svc: ServiceEntry) -> list[dict[str, Any]]:
        return self.arena_workload(str(svc.params["world"]), wiring.service_specs(self.wiring, svc))

    def arena_workload(
        self, world: str, specs: list[ChildSpec], *, map_config: str | None = None
    ) -> list[dict[str, Any]]:
        """An engine and its agent context in one pod: they come and go together.

        ``map_config``: a ConfigMap holding the engine's map (an arena made on request
        with a number of robots: its map is written for it), mounted at MAP_CONFIG.
        """
        containers = [self.container("engine", "engine", specs[0], "engine")]
        accounts = [a for s in specs for i, a in enumerate(s.argv) if s.argv[i - 1] == "--user"]
        volumes = self.volumes("engine", accounts)
        if len(specs) > 1:
            agent = self.container("agent", "agent", specs[1], "agent")
            agent["volumeMounts"][0]["name"] = "tls-agent"
            containers.append(agent)
            volumes.append(self.k.secret_volume("tls-agent", "wart-tls-agent"))
        if map_config is not None:
            volumes.append({"name": "map", "configMap": {"name": map_config}})
            mount = {"name": "map", "mountPath": str(MAP_CONFIG), "readOnly": True}
            containers[0]["volumeMounts"].append(mount)
        return self.k.workload("arena", world, containers, volumes, stateful=True)

    def scaled_runners(self) -> list[str]:
        """The Deployments of this host's runners scaled on the grader's queue."""
        return [
            object_name("runner", s.ident)
            for s in self.host.services
            if s.kind == "runner" and s.scale is not None
        ]

    def hosting(self) -> list[dict[str, Any]]:
        """The cluster's host: ``wart arena new`` makes arenas as workloads (arenas.py),
        with the rights to make and delete them in this namespace and nothing else."""
        host = self.host.name
        argv = ["kube", "host", "--lab", str(LAB_FILES / "lab.toml"), "--name", host]
        argv += ["--image", self.o.image, "--namespace", self.o.namespace]
        spec = ChildSpec("host", argv, keys.alive(self.lab.realm, AliveKind.HOST, host))
        c = self.container("host", "host", spec, "host")
        c["volumeMounts"].append({"name": "lab", "mountPath": str(LAB_FILES), "readOnly": True})
        volumes = [*self.volumes("host", []), {"name": "lab", "configMap": {"name": "wart-lab"}}]
        objects = self.k.workload("host", host, [c], volumes, stateful=False)
        objects[-1]["spec"]["template"]["spec"]["serviceAccountName"] = "wart-host"
        meta = self.k.meta("wart-host", "host", host)
        rules: list[dict[str, Any]] = []
        if self.host.arenas:
            rules += [
                {
                    "apiGroups": ["apps"],
                    "resources": ["statefulsets"],
                    "verbs": ["create", "delete", "get", "list"],
                },
                {
                    "apiGroups": [""],
                    "resources": ["configmaps"],
                    "verbs": ["create", "delete", "get"],
                },
            ]
        scaled = self.scaled_runners()
        if scaled:  # runners scaled on the grader's queue (runner_scale.py): those only
            rules.append(
                {
                    "apiGroups": ["apps"],
                    "resources": ["deployments/scale"],
                    "resourceNames": scaled,
                    "verbs": ["get", "patch"],
                }
            )
        binding = {
            "apiVersion": f"{RBAC}/v1",
            "kind": "RoleBinding",
            "metadata": meta,
            "roleRef": {
                "apiGroup": "rbac.authorization.k8s.io",
                "kind": "Role",
                "name": "wart-host",
            },
            "subjects": [
                {"kind": "ServiceAccount", "name": "wart-host", "namespace": self.o.namespace}
            ],
        }
        return [
            {"apiVersion": "v1", "kind": "ServiceAccount", "metadata": meta},
            {
                "apiVersion": "rbac.authorization.k8s.io/v1",
                "kind": "Role",
                "metadata": meta,
                "rules": rules,
            },
            binding,
            *objects,
        ]

    def viewer(self, svc: ServiceEntry) -> list[dict[str, Any]]:
        port = int(svc.params.get("http_port", 8080))
        svc = replace(svc, params={**svc.params, "http_host": "0.0.0.0"})
        spec = wiring.service_specs(self.wiring, svc)[0]
        c = self.container("viewer", "viewer", spec, "viewer")
        c["ports"] = [{"name": "http", "containerPort": port}]
        accounts = [spec.argv[i + 1] for i, a in enumerate(spec.argv) if a == "--user"]
        volumes = self.volumes("viewer", accounts)
        # Its data directory outlives the pod: what the pages have open (handover.py) is
        # found again by the next pod of an upgrade, and their tabs come back with them.
        objects = self.k.workload("viewer", svc.ident, [c], volumes, stateful=True)
        if self.podman:
            return objects
        name = objects[-1]["metadata"]["name"]
        # The page's public name: the host's first name that is not the router's Service's.
        outside = [n for n in self.host.names if not n.startswith(ROUTER) and "." in n]
        public = outside[0] if outside else "lab.example.org"
        ingress = {
            "apiVersion": "networking.k8s.io/v1",
            "kind": "Ingress",
            "metadata": {
                **self.k.meta(name, "viewer", svc.ident),
                # The page's websocket stays open for a whole session.
                "annotations": {"nginx.ingress.kubernetes.io/proxy-read-timeout": "3600"},
            },
            "spec": {
                "rules": [
                    {
                        "host": public,
                        "http": {
                            "paths": [
                                {
                                    "path": "/",
                                    "pathType": "Prefix",
                                    "backend": {
                                        "service": {"name": name, "port": {"number": port}}
                                    },
                                }
                            ]
                        },
                    }
                ]
            },
        }
        return [self.k.service(name, "viewer", svc.ident, port), *objects, ingress]

    # --- configuration and secrets -----------------------------------------------------

    def zenoh_configs(self, roles: list[str]) -> dict[str, Any]:
        """Every role's Zenoh config, the router's access rules in it. A Secret, not a
        ConfigMap: the rules say what each role may do, the configs where its key is."""
        zenoh = {f"{role}.json5": json.dumps(self.zenoh_config(role), indent=1) for role in roles}
        return self.k.secret("wart-zenoh", "lab", self.host.name, zenoh)

    def from_pki(self, roles: list[str]) -> list[dict[str, Any]]:
        """What ``wart certs lab`` made: the registry's public key, the service accounts'
        keys, each role's certificate, the identities, the registry's own key."""
        lab = self.lab
        pki = lab.security.pki
        public = _read({REGISTRY_PUB: pki / REGISTRY_PUB, ACCOUNTS: pki / ACCOUNTS})
        objects: list[dict[str, Any]] = [
            {
                "apiVersion": "v1",
                "kind": "ConfigMap",
                "metadata": self.k.meta("wart-lab", "lab", self.host.name),
                "data": {
                    REGISTRY_PUB: public[REGISTRY_PUB].strip(),
                    ACCOUNTS: public[ACCOUNTS],
                    # The host pod reads it (wart kube host): the lab's limits and arenas.
                    "lab.toml": lab.path.read_text(),
                },
            },
        ]
        for role in roles:
            tls = host_tls(pki, self.host.name, role)
            files = {"ca.pem": tls.ca, "cert.pem": tls.cert, "key.pem": tls.key}
            objects.append(self.k.secret(f"wart-tls-{role}", role, role, _read(files)))
        keys_dir = identity_path(pki, self.host.name, "any").parent
        identities = {
            path.name: path for path in sorted(keys_dir.glob("*.key")) if path.stem != "registry"
        }
        objects.append(self.k.secret("wart-identities", "lab", self.host.name, _read(identities)))
        if "registry" in self.host.kinds():
            key = registry_key_path(lab)
            key_file = _read({"registry.key": key})
            objects.append(self.k.secret("wart-registry-key", "registry", "registry", key_file))
        return objects

    def render(self) -> Rendered:
        out = Rendered()
        services = list(self.host.services)
        grader = next((s for s in services if s.kind == "grader"), None)
        roles = host_roles(self.lab, self.host.name)
        if not self.podman:  # in both parts: either may be applied first
            namespace = {"name": self.o.namespace, "labels": {"app.kubernetes.io/name": "wart"}}
            out.objects.append({"apiVersion": "v1", "kind": "Namespace", "metadata": namespace})
        if self.o.part != "workloads":
            out.objects += self.from_pki(roles)
        if self.o.part == "pki":
            return out
        out.objects.append(self.zenoh_configs(roles))
        out.objects += self.router()
        for svc in services:
            if svc.kind == "registry":
                out.objects += self.registry(svc, grader)
            elif svc.kind == "grader":
                if "registry" not in self.host.kinds():
                    out.skipped.append(
                        f"grader {svc.ident}: it writes the registry's database, "
                        "so it goes on the registry's host"
                    )
            elif svc.kind == "engine":
                out.objects += self.arena(svc)
            elif svc.kind == "viewer":
                out.objects += self.viewer(svc)
            elif svc.kind in ("chat", "agent", "runner", "camera", "lti"):
                out.objects += self.one_pod(svc)
            else:
                out.skipped.append(
                    f"{svc.kind} {svc.ident}: a bridge drives robots on this machine's serial "
                    "ports: run it with `wart host` on the machine they are plugged into"
                )
        if (self.host.arenas or self.scaled_runners()) and not self.podman:
            out.objects += self.hosting()
        elif self.host.arenas:
            out.skipped.append("arenas on request: they need a Kubernetes API (wart kube host)")
        return out


def _read(files: Mapping[str, Path]) -> dict[str, str]:
    """Text files' contents; a binary one (the registry's key: 32 bytes) as hex."""
    data = {}
    for key, path in files.items():
        try:
            raw = path.read_bytes()
            try:
                data[key] = raw.decode("ascii")
            except UnicodeDecodeError:
                data[key] = raw.hex()
        except OSError as exc:
            raise LabFileError(
                f"{path}: {exc.strerror}: run `wart certs lab --lab FILE` first"
            ) from None
    return data


def render(lab: LabFile, host_name: str, options: KubeOptions | None = None) -> Rendered:
    """The Kubernetes objects (or podman's pods) of one host of a lab file."""
    return Renderer(lab, lab.host(host_name), options or KubeOptions()).render()
