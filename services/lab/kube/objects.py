"""Kubernetes objects of any workload: names, labels, pods, StatefulSets or Deployments.

What does not depend on the lab: manifests.py says which workloads a lab
file's host has, this module how each is written down, in Kubernetes' or in
podman's dialect (``podman kube play`` runs Pods, Deployments, claims,
ConfigMaps and Secrets, but no StatefulSet and no Service).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Any

from services.lab.labfile import LabFileError

MODES = ("kubernetes", "podman")
_DNS_LABEL = re.compile(r"[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?")
_DNS_NAME = re.compile(r"[a-z0-9]([-a-z0-9.]{0,251}[a-z0-9])?")
_QUANTITY = re.compile(r"[1-9][0-9]{0,5}(Ki|Mi|Gi|Ti)")
_IMAGE = re.compile(r"[a-z0-9][a-z0-9._/:-]{0,254}(@sha256:[0-9a-f]{64})?")
PARTS = ("all", "workloads", "pki")
STATE = PurePosixPath("/var/lib/wart")  # every process's state directory
UID = 10001  # the image's user wart (deploy/container)


@dataclass(frozen=True)
class KubeOptions:
    image: str = "localhost/wart:latest"
    namespace: str = "wart"
    mode: str = "kubernetes"
    state_size: str = "1Gi"  # each StatefulSet's volume
    storage_class: str | None = None  # None: the cluster's default
    # all: everything; workloads: leave out what comes from the lab's PKI (the ConfigMap
    # wart-lab and the Secrets of certificates and keys); pki: only that
    part: str = "all"
    router_service_type: str = "ClusterIP"  # LoadBalancer/NodePort: students' tools outside


def labels(component: str, ident: str) -> dict[str, str]:
    return {
        "app.kubernetes.io/name": "wart",
        "app.kubernetes.io/component": component,
        "wart.lab/service": ident,
    }


def object_name(kind: str, ident: str) -> str:
    """A workload's name: a DNS label (lower case, digits, '-'), at most 52 characters
    so that a StatefulSet's pods and volumes stay under the 63 of a label."""
    clean = "".join(c if c.isalnum() else "-" for c in f"wart-{kind}-{ident}".lower())
    clean = "-".join(part for part in clean.split("-") if part)
    if len(clean) > 52:
        raise LabFileError(f"{kind} {ident!r}: the name {clean!r} is too long for Kubernetes")
    return clean


def _object(api: str, kind: str, meta: dict[str, Any], spec: dict[str, Any]) -> dict[str, Any]:
    return {"apiVersion": api, "kind": kind, "metadata": meta, "spec": spec}


class Objects:
    """Writes workloads for one namespace and one mode (``KubeOptions``)."""

    def __init__(self, options: KubeOptions) -> None:
        if options.mode not in MODES:
            raise LabFileError(f"mode {options.mode!r}: expected one of {', '.join(MODES)}")
        if options.part not in PARTS:
            raise LabFileError(f"part {options.part!r}: expected one of {', '.join(PARTS)}")
        checks: list[tuple[str, str, re.Pattern[str], str]] = [
            ("namespace", options.namespace, _DNS_LABEL, "a DNS label: a-z, 0-9, '-'"),
            ("state size", options.state_size, _QUANTITY, "a quantity such as 1Gi or 500Mi"),
            ("image", options.image, _IMAGE, "an image reference such as localhost/wart:1.0"),
        ]
        if options.storage_class is not None:
            checks.append(("storage class", options.storage_class, _DNS_NAME, "a DNS name"))
        for what, value, pattern, expected in checks:
            if not pattern.fullmatch(value):
                raise LabFileError(f"{what} {value!r}: expected {expected}")
        self.o = options
        self.podman = options.mode == "podman"

    def meta(self, name: str, component: str, ident: str) -> dict[str, Any]:
        return {"name": name, "namespace": self.o.namespace, "labels": labels(component, ident)}

    def pod_spec(
        self, containers: list[dict[str, Any]], volumes: list[dict[str, Any]]
    ) -> dict[str, Any]:
        spec: dict[str, Any] = {
            "securityContext": {
                "runAsUser": UID,
                "runAsGroup": UID,
                "fsGroup": UID,
                "runAsNonRoot": True,
            },
            "containers": containers,
            "volumes": volumes,
            "terminationGracePeriodSeconds": 15,
        }
        if self.podman:
            spec["hostNetwork"] = True
            for c in containers:  # a port is the host's already: podman refuses to map it
                c.pop("ports", None)
        return spec

    def workload(
        self,
        component: str,
        ident: str,
        containers: list[dict[str, Any]],
        volumes: list[dict[str, Any]],
        *,
        stateful: bool,
    ) -> list[dict[str, Any]]:
        """A StatefulSet of one with its volume at STATE (state that outlives the pod),
        or a Deployment; podman mode: a Deployment with a claim of the same name."""
        name = object_name(component, ident)
        meta = self.meta(name, component, ident)
        pod = self.pod_spec(containers, volumes)
        template = {"metadata": {"labels": meta["labels"]}, "spec": pod}
        selector = {"matchLabels": meta["labels"]}
        claim: dict[str, Any] = {
            "accessModes": ["ReadWriteOnce"],
            "resources": {"requests": {"storage": self.o.state_size}},
        }
        if self.o.storage_class:
            claim["storageClassName"] = self.o.storage_class
        mount = {"name": "state", "mountPath": str(STATE)}
        for c in containers:
            c["volumeMounts"].append(mount)
        if stateful and not self.podman:
            spec = {
                "serviceName": name,
                "replicas": 1,
                "selector": selector,
                # One pod at a time writes the volume: the old pod is gone before the new
                # one starts (a StatefulSet's ordered update), as Recreate would do.
                "podManagementPolicy": "OrderedReady",
                "updateStrategy": {"type": "RollingUpdate"},
                "template": template,
                "volumeClaimTemplates": [{"metadata": {"name": "state"}, "spec": claim}],
            }
            return [_object("apps/v1", "StatefulSet", meta, spec)]
        out: list[dict[str, Any]] = []
        if stateful:
            claim_name = f"{name}-state"
            out.append(
                {
                    "apiVersion": "v1",
                    "kind": "PersistentVolumeClaim",
                    "metadata": self.meta(claim_name, component, ident),
                    "spec": claim,
                }
            )
            volumes.append({"name": "state", "persistentVolumeClaim": {"claimName": claim_name}})
        else:
            volumes.append({"name": "state", "emptyDir": {}})
        spec = {
            "replicas": 1,
            "selector": selector,
            "strategy": {"type": "Recreate"},
            "template": template,
        }
        out.append(_object("apps/v1", "Deployment", meta, spec))
        return out

    def service(self, name: str, component: str, ident: str, port: int, **extra: Any) -> dict:
        return {
            "apiVersion": "v1",
            "kind": "Service",
            "metadata": self.meta(name, component, ident),
            "spec": {
                "selector": labels(component, ident),
                "ports": [{"name": component, "port": port, "targetPort": port}],
                **extra,
            },
        }

    def secret(
        self, name: str, component: str, ident: str, data: Mapping[str, str]
    ) -> dict[str, Any]:
        """A Secret of text files (stringData). For podman, a ConfigMap: podman 4.3's kube
        play mounts a Secret's ``data`` still base64-encoded and ignores ``stringData``."""
        meta = self.meta(name, component, ident)
        if self.podman:
            return {"apiVersion": "v1", "kind": "ConfigMap", "metadata": meta, "data": dict(data)}
        return {
            "apiVersion": "v1",
            "kind": "Secret",
            "metadata": meta,
            "type": "Opaque",
            "stringData": dict(data),
        }

    def secret_volume(self, name: str, secret: str, files: list[str] | None = None) -> dict:
        """A Secret as files readable by the pod's group (fsGroup: the image's user)."""
        items = [{"key": f, "path": f} for f in files or ()]
        if self.podman:  # the ConfigMap that stands for it (secret above); podman gives
            # the files to root whatever fsGroup says: readable by all, in a test's pods
            source: dict[str, Any] = {"name": secret, "defaultMode": 0o444}
            return {"name": name, "configMap": {**source, **({"items": items} if items else {})}}
        # optional: false, as Kubernetes takes it when unsaid: podman 4.3's kube play
        # dereferences the field without a check (a crash when it is missing).
        source = {"secretName": secret, "defaultMode": 0o440, "optional": False}
        if items:
            source["items"] = items
        return {"name": name, "secret": source}
