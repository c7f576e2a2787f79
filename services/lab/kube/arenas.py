"""Arenas on request in a cluster: ``wart arena new`` creates a workload, not a process.

``wart kube host`` answers the same ``host/<h>/spawn`` and ``host/<h>/load``
as ``wart host`` (the same rules: the ``host`` permission, names taken,
the lab's limits, who may stop what: services/lab/hosting.py), but an arena
it starts is a StatefulSet of one pod (engine and agent context, its volume
deleted with it) created through the Kubernetes API, and stopping it deletes
that. Placement on a node, restarts, a node lost: Kubernetes' job. It is
ready when its liveliness tokens are in the lab, as for a local arena.

The ``kubernetes`` package (the project's ``kubernetes`` extra) is imported
here only, when a lab runs in a cluster.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh
from kubernetes import client as k8s
from kubernetes.client.exceptions import ApiException
from urllib3.exceptions import HTTPError

from common.service import RequestError
from services.lab.hosting import Hosted, HostingPlan, HostingService
from services.lab.kube.manifests import MAP_CONFIG, Renderer
from services.lab.kube.objects import object_name
from services.lab.supervisor import ChildSpec, Supervisor
from services.lab.wiring import ENGINE_READY_TIMEOUT_S

ON_REQUEST = "wart.lab/on-request"  # the label of arenas made on request (their owner's)


@dataclass(frozen=True)
class ClusterPlan(HostingPlan):
    """A cluster host's plan: the pods' paths in the wiring, this process's own directory
    for what it writes (an arena's generated map, before it goes into a ConfigMap)."""

    local_dir: Path = Path(".")

    @property
    def state_dir(self) -> Path:
        return self.local_dir


class ArenaWorkloads:
    """Creates and deletes arenas' objects in one namespace through the Kubernetes API."""

    def __init__(self, renderer: Renderer, api: k8s.ApiClient) -> None:
        self.renderer = renderer
        self.namespace = renderer.o.namespace
        self.apps = k8s.AppsV1Api(api)
        self.core = k8s.CoreV1Api(api)
        self._calls = ThreadPoolExecutor(max_workers=1, thread_name_prefix="kube-api")

    def objects(self, world: str, specs: list[ChildSpec], owner: str) -> list[dict[str, Any]]:
        """The arena's StatefulSet, and the ConfigMap of its map when it was written for
        it (a number of robots asked for: the map lives in this process's directory)."""
        specs = list(specs)
        argv = list(specs[0].argv)
        i = argv.index("--map") + 1
        map_file = Path(argv[i])
        config: dict[str, Any] | None = None
        if not self.renderer.is_shipped(map_file):  # written here, or the lab's own map
            name = f"{object_name('arena', world)}-map"
            config = {
                "apiVersion": "v1",
                "kind": "ConfigMap",
                "metadata": self.renderer.k.meta(name, "arena", world),
                "data": {map_file.name: map_file.read_text()},
            }
            argv[i] = str(MAP_CONFIG / map_file.name)
            specs[0] = ChildSpec(specs[0].name, argv, specs[0].alive_key, specs[0].detail)
        map_config = config["metadata"]["name"] if config else None
        (workload,) = self.renderer.arena_workload(world, specs, map_config=map_config)
        workload["metadata"]["labels"][ON_REQUEST] = "true"
        workload["metadata"].setdefault("annotations", {})["wart.lab/owner"] = owner
        # Its volume goes with it: an arena on request keeps nothing once closed.
        workload["spec"]["persistentVolumeClaimRetentionPolicy"] = {
            "whenDeleted": "Delete",
            "whenScaled": "Retain",
        }
        return [config, workload] if config else [workload]

    def create(self, world: str, specs: list[ChildSpec], owner: str) -> str:
        """Make the arena's objects; "" when done, else why not (in words)."""
        objects = self.objects(world, specs, owner)
        return self._calls.submit(self._create, world, objects).result()

    def delete(self, world: str) -> str:
        """Delete the arena's objects (gone already is fine); "" when done, else why not."""
        return self._calls.submit(self._delete, world).result()

    # The API is called on a thread of its own, its errors turned into words there: a
    # client error keeps its frames, and through them its callers' (frames hold their
    # caller): the spawn request's query, held open past its reply, kept the asking
    # client waiting for its whole timeout (measured: 90 s).

    def _create(self, world: str, objects: list[dict[str, Any]]) -> str:
        try:
            for obj in objects:
                # The client sends a dict as it is (as kubectl would the YAML): the same
                # objects as `wart kube render`'s, not the client's model classes.
                body: Any = obj
                if obj["kind"] == "ConfigMap":
                    self.core.create_namespaced_config_map(self.namespace, body)
                else:
                    self.apps.create_namespaced_stateful_set(self.namespace, body)
        except ApiException as exc:
            return f"the cluster refused arena {world}: {exc.status} {exc.reason}"
        except (HTTPError, OSError) as exc:  # no API server answered
            return f"the Kubernetes API did not answer ({type(exc).__name__})"
        return ""

    def _delete(self, world: str) -> str:
        name = object_name("arena", world)
        for delete, what in (
            (self.apps.delete_namespaced_stateful_set, name),
            (self.core.delete_namespaced_config_map, f"{name}-map"),
        ):
            try:
                delete(what, self.namespace, propagation_policy="Foreground")
            except ApiException as exc:
                if exc.status != 404:  # gone already (or never made: no map of its own)
                    return f"the cluster did not delete arena {world}: {exc.status} {exc.reason}"
            except (HTTPError, OSError) as exc:
                return f"the Kubernetes API did not answer ({type(exc).__name__})"
        return ""


class ClusterHosting(HostingService):
    """The hosting service of a lab in a cluster: arenas are workloads (see the module)."""

    def __init__(
        self,
        session: zenoh.Session,
        plan: ClusterPlan,
        supervisor: Supervisor,
        workloads: ArenaWorkloads,
    ) -> None:
        super().__init__(session, plan, supervisor)
        self.workloads = workloads

    def _busy(self, cpu: float, available_mb: float) -> str:
        """Never busy: the scheduler places the pod where the cluster has room (this
        process's own machine says nothing of that); the arena count is still capped."""
        return ""

    def _start(
        self, table: dict[str, Hosted], name: str, hosted: Hosted, specs: list[ChildSpec]
    ) -> None:
        with self._lock:
            table[name] = hosted
        refused = self.workloads.create(name, specs, hosted.info.owner)
        if refused:
            with self._lock:
                table.pop(name, None)
            self.log.warning("arena %s: %s", name, refused)
            raise RequestError("unavailable", refused)
        watch = self.supervisor.watch
        for spec in specs:
            if watch is None or spec.alive_key is None:
                continue
            stopped = self._stopped.is_set
            if not watch.wait(spec.alive_key, ENGINE_READY_TIMEOUT_S, abort=stopped):
                self._discard(table, name)
                raise RequestError(
                    "internal",
                    f"{spec.name} did not come up in the cluster: see its pod "
                    f"({object_name('arena', name)}-0)",
                )

    def _discard(self, table: dict[str, Hosted], name: str) -> None:
        with self._lock:
            table.pop(name, None)
        failed = self.workloads.delete(name)
        if failed:
            self.log.warning("%s", failed)
            raise RequestError("internal", failed)
