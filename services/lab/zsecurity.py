"""Zenoh transport security for a multi-host lab: TLS, mutual TLS and access control.

Every link of a lab is ``tls/`` with mutual authentication against the lab's
CA: routers between themselves and every process to its host's router. The
routers enforce access-control rules (default deny) keyed on the certificate's
common name, which names a *role* (``engine``, ``agent``, ``student``...):
what each role may publish, subscribe to, serve, ask, and announce is the
table :data:`ROLE_GRANTS` below, derived from the lab's dataflow table
(common/dataflow.py). Application-level
authentication (signed envelopes, session tokens, leases) stays in force on
top: the transport rules say which *kind of process* may emit on a key, the
envelopes say which *user*.

Facts of zenoh 1.10's ACL this relies on (measured, see tests): the three
lists rules/subjects/policies are all needed; under default deny a declaration
must be allowed too (``declare_subscriber``, ``declare_queryable``,
``liveliness_token``...); a query is checked on ingress from the caller and on
egress toward the queryable, and its reply the other way round; rules match by
key-expression inclusion; a denied put is dropped silently.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common import dataflow, keys
from common.keys import realm_root
from common.zconfig import NetworkOptions
from services.lab.certs import CA_CERT
from services.lab.labfile import LabFile

# The roles, i.e. the certificate common names the rules know (common/dataflow.py):
# a host's processes use the certificate of their role from that host's
# directory; people's tools use a client certificate (student, admin).
ROLES = dataflow.ROLES


@dataclass(frozen=True)
class Grant:
    """One capability of a role on some keys (relative to ``wart/<realm>/``)."""

    verb: str  # pub, sub, serve, ask, token, watch
    keys: tuple[str, ...]


# What a verb needs from the router, per flow (seen from the router: ingress is
# what the process sends in, egress what the router sends out to it).
VERB_MESSAGES: dict[str, dict[str, tuple[str, ...]]] = {
    # publishers also receive subscriber declarations (Zenoh's matching status)
    "pub": {"ingress": ("put", "delete"), "egress": ("declare_subscriber",)},
    "sub": {"ingress": ("declare_subscriber",), "egress": ("put", "delete")},
    "serve": {"ingress": ("declare_queryable", "reply"), "egress": ("query",)},
    "ask": {"ingress": ("query",), "egress": ("reply", "declare_queryable")},
    "token": {"ingress": ("liveliness_token",), "egress": ()},
    "watch": {
        "ingress": ("declare_liveliness_subscriber", "liveliness_query"),
        "egress": ("liveliness_token", "reply"),
    },
}


def _grants(role: str) -> tuple[Grant, ...]:
    """A role's rights: one grant per verb, over every key the dataflow gives it that verb on."""
    by_verb: dict[str, list[str]] = {}
    for verb, pattern in dataflow.role_verbs(role):
        patterns = by_verb.setdefault(verb, [])
        if pattern not in patterns:
            patterns.append(pattern)
    return tuple(Grant(verb, tuple(patterns)) for verb, patterns in by_verb.items())


# What each role may publish, subscribe to, serve, ask, announce and watch: the
# dataflow table's producers and consumers, and nothing else.
# A router holds everything (acl_config): it forwards for the others.
ROLE_GRANTS: dict[str, tuple[Grant, ...]] = {
    role: _grants(role) for role in ROLES if role != "router"
}


def acl_config(
    realm: str,
    role_names: Mapping[str, Iterable[str]],
) -> dict[str, Any]:
    """The ``access_control`` section for every router of the lab.

    ``role_names`` maps a role to the certificate common names that hold it
    (normally the role's own name; students and admins may have several).
    Routers hold everything (they forward for the others); the admin role
    also reaches the routers' admin space (``@/**``) for ``wart doctor``.
    """
    root = realm_root(realm)
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    all_messages = sorted(
        {m for flows in VERB_MESSAGES.values() for ms in flows.values() for m in ms}
    )
    rules.append(
        {
            "id": "router-all",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": all_messages,
            "key_exprs": ["**", keys.admin_space_all()],
        }
    )
    rules.append(
        {
            "id": "admin-space",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": ["query", "reply", "declare_queryable"],
            "key_exprs": [keys.admin_space_all()],
        }
    )
    for role, grants in sorted(ROLE_GRANTS.items()):
        ids = []
        for n, grant in enumerate(grants):
            for flow, messages in VERB_MESSAGES[grant.verb].items():
                if not messages:
                    continue
                rule_id = f"{role}-{n}-{grant.verb}-{flow}"
                rules.append(
                    {
                        "id": rule_id,
                        "permission": "allow",
                        "flows": [flow],
                        "messages": list(messages),
                        "key_exprs": [f"{root}/{key}" for key in grant.keys],
                    }
                )
                ids.append(rule_id)
        names = sorted(set(role_names.get(role, (role,))))
        if not names:
            continue
        subjects.append({"id": f"{role}s", "cert_common_names": names})
        policies.append({"id": f"{role}-policy", "rules": ids, "subjects": [f"{role}s"]})
    router_names = sorted(set(role_names.get("router", ("router",))))
    subjects.append({"id": "routers", "cert_common_names": router_names})
    policies.append({"id": "router-policy", "rules": ["router-all"], "subjects": ["routers"]})
    policies.append({"id": "admin-space-policy", "rules": ["admin-space"], "subjects": ["admins"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


@dataclass(frozen=True)
class TlsFiles:
    ca: Path
    cert: Path
    key: Path

    def missing(self) -> list[Path]:
        return [p for p in (self.ca, self.cert, self.key) if not p.is_file()]


def host_tls(pki: Path, host: str, role: str) -> TlsFiles:
    """A host process's certificate: ``<pki>/<host>/<role>.pem``."""
    return TlsFiles(pki / CA_CERT, pki / host / f"{role}.pem", pki / host / f"{role}.key")


def client_tls(pki: Path, name: str) -> TlsFiles:
    """A person's tool's certificate: ``<pki>/clients/<name>.pem``."""
    return TlsFiles(pki / CA_CERT, pki / "clients" / f"{name}.pem", pki / "clients" / f"{name}.key")


def zenoh_security(
    tls: TlsFiles,
    *,
    lease_ms: int,
    acl: Mapping[str, Any] | None = None,
    check_files: bool = True,
) -> dict[str, Any]:
    """The security part of a process's Zenoh config (a JSON5 document).

    Lists its certificate for both listening and connecting (a router does
    both), requires the peer's certificate (mutual TLS) and checks names
    on connect. ``lease_ms`` is how long a silent link stays up.
    ``check_files``: whether the files must exist here (not for a config
    written for another machine or a container, where they are mounted).
    """
    missing = tls.missing() if check_files else []
    if missing:
        raise FileNotFoundError(
            f"missing {', '.join(str(p) for p in missing)}: run `wart certs lab --lab FILE` "
            "(or `wart certs host`/`client`) and copy the files to this host"
        )
    conf: dict[str, Any] = {
        "transport": {
            "link": {
                "tls": {
                    "root_ca_certificate": str(tls.ca),
                    "listen_certificate": str(tls.cert),
                    "listen_private_key": str(tls.key),
                    "connect_certificate": str(tls.cert),
                    "connect_private_key": str(tls.key),
                    "enable_mtls": True,
                    "verify_name_on_connect": True,
                },
                "tx": {"lease": lease_ms, "keep_alive": 4},
            }
        }
    }
    if acl is not None:
        conf["access_control"] = dict(acl)
    return conf


def write_config(path: Path, conf: Mapping[str, Any]) -> Path:
    """Write a Zenoh config (JSON is valid JSON5); mode 0600, it names key files."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(conf, indent=2) + "\n")
    path.chmod(0o600)
    return path


def client_options(
    lab: LabFile,
    cert: str,
    *,
    connect: tuple[str, ...] = (),
    registry_key: str | None = None,
) -> NetworkOptions:
    """Network options for a person's tool (arena, doctor, chat) joining a lab over mTLS.

    ``cert`` names a client certificate in ``<pki>/clients/``; without
    ``connect`` the tool may reach any host's router (the first that answers).
    """
    tls = client_tls(lab.security.pki, cert)
    link = zenoh_security(tls, lease_ms=lab.lease_ms)["transport"]["link"]
    return NetworkOptions(
        realm=lab.realm,
        mode="client",
        connect=connect or tuple(h.endpoint for h in lab.hosts),
        registry_key=registry_key,
        extra={"transport/link/tls": link["tls"], "transport/link/tx/lease": lab.lease_ms},
    )
