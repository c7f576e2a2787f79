"""Zenoh transport security for a multi-host lab: TLS, mutual TLS and access control.

Every link of a lab is ``tls/`` with mutual authentication against the lab's
CA: routers between themselves and every process to its host's router. The
routers enforce access-control rules (default deny) keyed on the certificate's
common name, which names a *role* (``engine``, ``agent``, ``student``...):
what each role may publish, subscribe to, serve, ask, and announce is the
table :data:`ROLE_GRANTS` below, written once as data. Application-level
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

from common import keys
from common.keys import AliveKind, realm_root
from common.zconfig import NetworkOptions
from services.lab.certs import CA_CERT
from services.lab.labfile import LabFile

# The roles, i.e. the certificate common names the rules know. A host's
# processes use the certificate of their role from that host's directory;
# people's tools use a client certificate (student, admin).
ROLES = (
    "router",
    "host",
    "registry",
    "chat",
    "engine",
    "bridge",
    "agent",
    "runner",
    "grader",
    "lti",
    "viewer",
    "camera",
    "student",
    "admin",
)
SERVICE_ROLES = {
    "registry", "chat", "engine", "bridge", "agent", "viewer", "runner", "grader", "camera",
    "lti",
}  # fmt: skip


@dataclass(frozen=True)
class Grant:
    """One capability of a role on some keys (relative to ``wart/<realm>/``)."""

    verb: str  # pub, sub, serve, ask, token, watch
    keys: tuple[str, ...]


def _g(verb: str, *patterns: str) -> Grant:
    return Grant(verb, patterns)


W = keys.wildcard  # every pattern below is built from the key builders


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

# Every service logs in (or checks tokens) with the registry and follows presence.
_SERVICE_BASE = (
    _g(
        "ask",
        W(keys.registry_login),
        W(keys.registry_logout),
        W(keys.registry_directory),
        W(keys.registry_revocations),
    ),
    _g("sub", W(keys.registry_revocations), W(keys.user_inbox)),
    _g("watch", W(keys.alive_all)),
)
# What people's processes need: log in, the directory, rooms, watching worlds,
# driving robots they hold a lease on (the engine checks the lease), private
# messages, asking hosts for arenas (the host checks the `host` permission).
_PEOPLE = (
    _g(
        "ask",
        W(keys.registry_login),
        W(keys.registry_logout),
        W(keys.registry_directory),
        W(keys.registry_admin),
    ),
    # The audit trail: the registry answers only admins (it checks the permission).
    _g("ask", W(keys.registry_revocations), W(keys.registry_audit)),
    _g("sub", W(keys.registry_revocations), W(keys.user_inbox)),
    # ctx/*/output: a controller run from a student's machine (wart control)
    # reports its output to the context, which checks the sender holds the lease.
    _g("pub", W(keys.user_inbox), W(keys.ctx_in), W(keys.ctx_output), W(keys.agent_cmd)),
    _g("pub", W(keys.world_commands)),
    _g("ask", W(keys.ctx_join), W(keys.ctx_leave), W(keys.ctx_request), W(keys.ctx_state)),
    _g("ask", W(keys.ctx_dryrun), W(keys.ctx_status)),
    _g("sub", W(keys.ctx_events)),
    _g("sub", W(keys.world_frame), W(keys.world_sensors), W(keys.agent_sensors)),
    _g("token", W(keys.agent_watch)),
    _g("sub", W(keys.world_samples)),
    # a real arena's video and tracked poses, watched like its frames
    _g("sub", W(keys.camera_all), W(keys.world_tracked)),
    _g("ask", W(keys.world_snapshot), W(keys.world_edit), W(keys.world_map)),
    _g("ask", W(keys.world_robots)),
    _g("sub", W(keys.host_load)),
    _g("ask", W(keys.host_load), W(keys.host_spawn), W(keys.runner_run)),
    _g("ask", W(keys.grader_request)),  # submissions and leaderboards (issue 36)
    _g("sub", W(keys.grader_standings)),  # competitions' standings, live (sealed)
    _g("sub", W(keys.grader_changed)),  # a course's submissions changed (no score in it)
    _g("token", W(keys.alive, kind=AliveKind.USER)),
    _g("watch", W(keys.alive_all)),
)

ROLE_GRANTS: dict[str, tuple[Grant, ...]] = {
    "registry": (
        _g("serve", W(keys.registry_all)),
        _g("pub", W(keys.registry_revocations), W(keys.user_inbox)),
        _g("sub", W(keys.registry_report)),  # services' privileged actions, for the audit
        _g("ask", W(keys.ctx_state)),
        _g("token", W(keys.alive, kind=AliveKind.REGISTRY)),
        _g("watch", W(keys.alive_all)),
    ),
    "chat": (
        *_SERVICE_BASE,
        _g("serve", W(keys.ctx_join), W(keys.ctx_leave), W(keys.ctx_state), W(keys.ctx_request)),
        _g("sub", W(keys.ctx_in)),
        _g("pub", W(keys.ctx_events), W(keys.registry_report)),  # kicks, to the audit
        _g("token", W(keys.alive, kind=AliveKind.CONTEXT)),
    ),
    # Agent contexts: a chat room plus the robots' queues; the only role that
    # may publish leases. They hear controllers' output (runner, wart control).
    "agent": (
        *_SERVICE_BASE,
        _g("serve", W(keys.ctx_join), W(keys.ctx_leave), W(keys.ctx_state), W(keys.ctx_request)),
        _g("sub", W(keys.ctx_in), W(keys.ctx_output)),
        _g("pub", W(keys.ctx_events), W(keys.agent_lease), W(keys.world_estop)),
        _g("pub", W(keys.registry_report)),  # kicks, stops, settings: to the audit trail
        _g("serve", W(keys.ctx_dryrun), W(keys.ctx_status)),
        _g("sub", W(keys.world_frame), W(keys.agent_sensors)),
        # a real run's recording carries the camera's frames and tracked poses
        _g("sub", W(keys.camera_frame), W(keys.world_tracked)),
        _g("token", W(keys.agent_watch)),
        _g("ask", W(keys.world_snapshot), W(keys.runner_run), W(keys.runner_dryrun)),
        _g("token", W(keys.alive, kind=AliveKind.CONTEXT)),
    ),
    # Engines and bridges: the only roles that publish world frames and samples.
    "engine": (
        *_SERVICE_BASE,
        _g("pub", W(keys.world_frame), W(keys.world_sensors), W(keys.agent_sensors)),
        _g("pub", W(keys.world_samples)),
        _g("sub", W(keys.agent_cmd), W(keys.world_commands), W(keys.agent_lease)),
        _g("sub", W(keys.world_estop)),
        _g("watch", W(keys.agent_watch)),
        _g("serve", W(keys.world_snapshot), W(keys.world_edit), W(keys.world_map)),
        _g("serve", W(keys.world_robots)),
        _g("token", W(keys.alive, kind=AliveKind.WORLD)),
    ),
    # The runner is the parent of untrusted code: a client like a student's, that
    # may command robots (the engine or bridge obeys only the lease holder) and
    # report output, but never publish frames, samples or leases. Its sandboxes
    # have no network at all; they talk to it over a pipe.
    "runner": (
        *_SERVICE_BASE,
        _g(
            "serve",
            W(keys.runner_run),
            W(keys.runner_dryrun),
            W(keys.runner_episode),
            W(keys.runner_heat),  # a competition's heat of several entries
            W(keys.runner_grade),  # a teacher's grader function on a real attempt's data
        ),
        _g("pub", W(keys.agent_cmd), W(keys.world_commands), W(keys.ctx_output)),
        _g("sub", W(keys.agent_sensors), W(keys.world_samples), W(keys.agent_lease)),
        _g("token", W(keys.agent_watch)),
        _g("sub", W(keys.world_frame)),
        _g("ask", W(keys.world_snapshot)),
        _g("token", W(keys.alive, kind=AliveKind.RUNNER)),
    ),
    # The grader reads the registry's database (it runs on the registry's host) and
    # hands episodes to runners; it commands no robot.
    "grader": (
        *_SERVICE_BASE,
        _g("serve", W(keys.grader_request)),
        _g("pub", W(keys.grader_standings)),  # a competition's standings as heats end
        _g("pub", W(keys.grader_changed)),  # a submission queued, grading, graded, failed
        _g("pub", W(keys.grader_graded)),  # each graded submission (the LTI tool's passback)
        _g("ask", W(keys.runner_episode), W(keys.runner_heat), W(keys.runner_grade)),
        _g("token", W(keys.alive, kind=AliveKind.GRADER)),
    ),
    # The LTI tool faces browsers and LMSs: it asks the registry for launched users'
    # accounts and hears graded submissions; it commands nothing.
    "lti": (
        *_SERVICE_BASE,
        _g("ask", W(keys.registry_lti)),
        _g("ask", W(keys.grader_request)),  # scores it missed, read back (never written)
        _g("sub", W(keys.grader_graded)),
        _g("token", W(keys.alive, kind=AliveKind.LTI)),
    ),
    "host": (
        *_SERVICE_BASE,
        _g("serve", W(keys.host_spawn), W(keys.host_load)),
        _g("pub", W(keys.host_load)),
        _g("token", W(keys.alive, kind=AliveKind.HOST)),
    ),
    # The viewer is a gateway: browsers' users act through it with their own
    # sessions, so it holds exactly people's rights, plus its presence.
    "viewer": (*_PEOPLE, _g("token", W(keys.alive, kind=AliveKind.VIEWER))),
    "student": _PEOPLE,
    # Operators' tools (wart doctor, wart arena): people's rights plus the
    # routers' admin space (links, sessions) and every load report.
    "admin": _PEOPLE,
}
# A bridge is an engine whose robots' poses a camera may correct.
ROLE_GRANTS["bridge"] = (*ROLE_GRANTS["engine"], _g("sub", W(keys.world_tracked)))
# A camera over a real arena: it learns the arena from the world's snapshot and
# publishes what it sees; it logs in to nothing (its frames are as public as the
# world's, and the routers' rules say who may put them).
ROLE_GRANTS["camera"] = (
    _g("ask", W(keys.world_snapshot)),
    _g("pub", W(keys.camera_frame), W(keys.camera_floor), W(keys.camera_status)),
    _g("pub", W(keys.world_tracked)),
    _g("token", W(keys.alive, kind=AliveKind.CAMERA)),
)


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
) -> dict[str, Any]:
    """The security part of a process's Zenoh config (a JSON5 document).

    Lists its certificate for both listening and connecting (a router does
    both), requires the peer's certificate (mutual TLS) and checks names
    on connect. ``lease_ms`` is how long a silent link stays up.
    """
    missing = tls.missing()
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
