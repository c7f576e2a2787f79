"""Runners scaled on the grader's queue depth, by the cluster's host (``wart kube host``).

The grader puts its depth (submissions queued and being graded) every few
seconds on ``grader/<name>/queue``; this loop reads it and sets the runner
Deployment's replicas through the scale subresource, between the runner's
``min_replicas`` and ``max_replicas`` in the lab file: up at once (a class
submitting before a deadline waits for nothing), down only once the depth has
stayed low for ``cooldown_s`` (a queue that empties and fills again between
two submissions does not restart pods). When the API does not answer, the
runners stay as they are and grading goes on with them; the log says so, and
says when the API answers again.

Why not a HorizontalPodAutoscaler on an external metric: it needs a metrics
adapter in the cluster (Prometheus and its adapter, or KEDA) that the lab does
not ship and that cannot be tested here; the depth is the lab's own message,
and this process already holds the cluster's API client (docs/DEPLOY.md).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import zenoh
from kubernetes import client as k8s
from kubernetes.client.exceptions import ApiException
from urllib3.exceptions import HTTPError

from common import keys
from common.messages import GraderQueue, MessageError, decode
from common.worker import Worker
from services.lab.labfile import RunnerScale

PERIOD_S = 5.0  # how often the depth is weighed (the grader puts it every 5 s)
STALE_S = 20.0  # a grader not heard for this long counts for nothing
# A scale patch is a JSON merge patch: the client's default for a dict is a JSON patch
# (a list of operations), which an API server refuses for this body.
MERGE_PATCH = "application/merge-patch+json"


@dataclass
class ScaleRule:
    """Depth to replicas for one runner Deployment: bounds, and the cool-down's memory."""

    scale: RunnerScale
    _low_since: float | None = field(default=None, init=False)
    _window_high: int = field(default=0, init=False)

    def wanted(self, depth: int) -> int:
        """The replicas ``depth`` submissions need: one pod per ``per_replica``, bounded."""
        s = self.scale
        return max(s.min_replicas, min(s.max_replicas, math.ceil(depth / s.per_replica)))

    def decide(self, depth: int, current: int, now: float) -> int:
        """The replicas to have now (``current`` when nothing changes)."""
        want = self.wanted(depth)
        bounded = max(self.scale.min_replicas, min(self.scale.max_replicas, current))
        if want >= bounded:
            self._low_since = None
            return want  # more at once (or back within the bounds)
        # Fewer would do: only once the depth stayed low for the whole cool-down, and
        # then to the most that window needed (as an HPA's stabilization window does).
        if self._low_since is None:
            self._low_since, self._window_high = now, want
            return bounded
        self._window_high = max(self._window_high, want)
        if now - self._low_since < self.scale.cooldown_s:
            return bounded
        self._low_since = None
        return self._window_high


class RunnerScaler:
    """Reads the graders' depth, patches the runners' Deployments' scale (see the module)."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        api: k8s.ApiClient,
        namespace: str,
        runners: Mapping[str, RunnerScale],  # Deployment name -> its scaling
        *,
        period: float = PERIOD_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.apps = k8s.AppsV1Api(api)
        self.namespace = namespace
        self.rules = {name: ScaleRule(scale) for name, scale in runners.items()}
        self.replicas: dict[str, int] = {}  # as last read or set
        self.period = period
        self.clock = clock
        self.log = logging.getLogger("kube.runners")
        self._heard: dict[str, tuple[float, GraderQueue]] = {}
        self._lock = threading.Lock()
        self._api_down = False
        self._silent = False
        self._sub = session.declare_subscriber(keys.grader_queue_all(realm), self._on_depth)
        self._worker = Worker(self._run, "runner-scale")

    def start(self) -> RunnerScaler:
        self._worker.start()
        return self

    def stop(self) -> None:
        self._worker.stopping.set()
        self._sub.undeclare()
        self._worker.stop(10.0)

    def _on_depth(self, sample: zenoh.Sample) -> None:
        try:
            depth = decode(sample.payload, GraderQueue)
        except MessageError as exc:  # the routers let only the grader put here
            self.log.warning("dropped a queue depth on %s: %s", sample.key_expr, exc)
            return
        with self._lock:
            self._heard[depth.grader] = (self.clock(), depth)

    def depth(self) -> int | None:
        """Submissions queued and being graded, over the graders heard lately (None: none)."""
        now = self.clock()
        with self._lock:
            fresh = [d for t, d in self._heard.values() if now - t <= STALE_S]
        return sum(d.queued + d.running for d in fresh) if fresh else None

    def _run(self) -> None:
        while not self._worker.wait(self.period):
            self.step()

    def step(self) -> None:
        """One look at the depth, and a patch where the replicas should change."""
        depth = self.depth()
        if depth is None:
            if not self._silent:
                self._silent = True
                self.log.warning("no grader's queue depth heard: runners left as they are")
            return
        self._silent = False
        for name, rule in self.rules.items():
            try:
                current = self.replicas.get(name)
                if current is None:
                    current = self._read(name)
                want = rule.decide(depth, current, self.clock())
                if want != current:
                    self._patch(name, want)
                    self.log.info(
                        "%s: %d -> %d replicas (%d submissions queued or grading)",
                        name,
                        current,
                        want,
                        depth,
                    )
            except ApiException as exc:
                self._down(name, f"the cluster refused: {exc.status} {exc.reason}")
                continue
            except (HTTPError, OSError) as exc:
                self._down(name, f"the Kubernetes API did not answer ({type(exc).__name__})")
                continue
            if self._api_down:
                self._api_down = False
                self.log.warning("the Kubernetes API answers again: runners scaled again")

    def _down(self, name: str, why: str) -> None:
        self.replicas.pop(name, None)  # read again once the API answers
        if not self._api_down:
            self._api_down = True
            self.log.warning(
                "%s: %s; its runners stay as they are and grading goes on with them", name, why
            )

    def _read(self, name: str) -> int:
        found: Any = self.apps.read_namespaced_deployment_scale(name, self.namespace)
        self.replicas[name] = int(found.spec.replicas or 0)
        return self.replicas[name]

    def _patch(self, name: str, replicas: int) -> None:
        body: Any = {"spec": {"replicas": replicas}}
        self.apps.patch_namespaced_deployment_scale(
            name, self.namespace, body, _content_type=MERGE_PATCH
        )
        self.replicas[name] = replicas
