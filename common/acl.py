"""The function-based access-control model (thesis 5.5), shared by the registry and services.

A user holds *grants*: a permission (``kick``) or a role (``role:instructor``),
each in a *scope*: ``""`` everywhere, ``ctx/<ctx>`` in one context, or
``agent/<ctx>/<agent>`` for one agent of an agent context. Roles are named
permission sets. At login the registry expands roles and writes the result
into the session token: ``permissions`` (global) and ``grants`` (scope ->
permissions), so a service decides offline with :meth:`Principal.allowed`.

Credential types are pluggable: each kind has a name stored in the registry's
database and a check (services/registry/accounts_db.py); the client side of the
Ed25519 key credential is :func:`key_login_binding`.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Iterable, Mapping

from common.keys import check_ident
from common.messages.auth import ALL_PERMISSIONS

ROLE_PREFIX = "role:"

DEFAULT_ROLES: dict[str, frozenset[str]] = {
    "student": frozenset({"join", "chat", "control", "deploy"}),
    "instructor": frozenset({"join", "chat", "control", "deploy", "edit_map", "kick", "host"}),
    "admin": frozenset({"join", "chat", "control", "deploy", "edit_map", "kick", "host", "admin"}),
    # Contexts, engines, runners and bridges. ``host`` lets a room's events be
    # trusted by clients (events come from a session that may host contexts).
    "service": frozenset({"lease", "world", "run", "host", "join"}),
    # A gateway for people (the web viewer): it only vouches for the address a
    # browser's login comes from, so the registry throttles each browser apart.
    "gateway": frozenset({"vouch"}),
    # The lti service (services/lti/): it may ask the registry for a launched LMS user's
    # account (registry/lti), which no other role may; no permission beyond that.
    "lti": frozenset(),
}

CREDENTIAL_KINDS = ("password", "ed25519")

KEY_LOGIN_MAX_AGE = 60.0
"""Seconds a signed key login stays valid (clock skew included)."""


class AclError(ValueError):
    """A grant, role or scope is malformed; the message says which."""


# The registry account of each service kind that logs in, named after its ident
# (services/lab/wiring.py makes them). Engines and bridges log in only when asked.
SERVICE_ACCOUNT_PREFIX = {
    "chat": "chat-",
    "agent": "ctx-",
    "runner": "runner-",
    "grader": "grader-",
    # The LTI tool's account has the lti role only: it asks the registry for launched users.
    "lti": "lti-",
    "engine": "engine-",
    "bridge": "bridge-",
    # The viewer's account has the gateway role only: it vouches for browsers' addresses.
    "viewer": "viewer-",
}
_SERVICE_WORDS = {
    "chat": "chat room",
    "agent": "context",
    "runner": "runner",
    "grader": "grader",
    "lti": "LTI tool",
    "engine": "engine",
    "bridge": "Khepera bridge",
    "viewer": "web viewer",
}


def account_in_words(account: str) -> str:
    """A service's account as people say it ("runner-runner": "the runner"); a person's as is."""
    for kind, prefix in SERVICE_ACCOUNT_PREFIX.items():
        if account.startswith(prefix) and len(account) > len(prefix):
            ident = account[len(prefix) :]
            words = _SERVICE_WORDS[kind]
            return f"the {words}" if ident == kind else f"the {words} {ident}"
    return account


def context_scope(ctx: str) -> str:
    return f"ctx/{check_ident('context', ctx)}"


def agent_scope(ctx: str, agent: str) -> str:
    return f"agent/{check_ident('context', ctx)}/{check_ident('agent', agent)}"


def check_scope(scope: str) -> str:
    """``scope`` if it is "", ctx/<ctx> or agent/<ctx>/<agent>; else AclError."""
    if scope == "":
        return scope
    parts = scope.split("/")
    try:
        if parts[0] == "ctx" and len(parts) == 2:
            return context_scope(parts[1])
        if parts[0] == "agent" and len(parts) == 3:
            return agent_scope(parts[1], parts[2])
    except ValueError as exc:
        raise AclError(f"bad scope {scope!r}: {exc}") from None
    raise AclError(f"bad scope {scope!r}: use '' (everywhere), ctx/ROOM or agent/CTX/AGENT")


def check_grant(grant: str, roles: Mapping[str, frozenset[str]] = DEFAULT_ROLES) -> str:
    """``grant`` if it names a permission or a known role; else AclError."""
    if grant.startswith(ROLE_PREFIX):
        if grant[len(ROLE_PREFIX) :] not in roles:
            raise AclError(f"unknown role {grant[len(ROLE_PREFIX) :]!r}: one of {', '.join(roles)}")
        return grant
    if grant not in ALL_PERMISSIONS:
        raise AclError(
            f"unknown permission {grant!r}: one of {', '.join(ALL_PERMISSIONS)} "
            f"or role:{'/'.join(roles)}"
        )
    return grant


def expand(
    grants: Iterable[tuple[str, str]], roles: Mapping[str, frozenset[str]] = DEFAULT_ROLES
) -> tuple[frozenset[str], dict[str, list[str]], list[str]]:
    """(global permissions, scope -> permissions, global role names) of (scope, grant) pairs.

    A grant naming a role that no longer exists is ignored (the database may
    have been edited by hand); it never widens access.
    """
    everywhere: set[str] = set()
    scoped: dict[str, set[str]] = {}
    role_names: list[str] = []
    for scope, grant in grants:
        if grant.startswith(ROLE_PREFIX):
            name = grant[len(ROLE_PREFIX) :]
            perms = set(roles.get(name, ()))
            if scope == "" and name in roles:
                role_names.append(name)
        elif grant in ALL_PERMISSIONS:
            perms = {grant}
        else:
            continue
        (everywhere if scope == "" else scoped.setdefault(scope, set())).update(perms)
    return (
        frozenset(everywhere),
        {scope: sorted(perms) for scope, perms in sorted(scoped.items())},
        sorted(role_names),
    )


def allowed(
    permission: str,
    everywhere: Iterable[str],
    scoped: Mapping[str, Iterable[str]],
    scope: str | None = None,
    *,
    restricted: bool = False,
) -> bool:
    """Whether ``permission`` holds in ``scope``.

    A global grant holds everywhere unless the scope is ``restricted`` (a
    private room): then only grants in that scope count, and ``admin`` always.
    An agent scope also inherits the grants of its context.
    """
    everywhere = set(everywhere)
    if "admin" in everywhere:
        return True
    if scope:
        if permission in scoped.get(scope, ()):
            return True
        if scope.startswith("agent/"):
            ctx_scope = "ctx/" + scope.split("/")[1]
            if permission in scoped.get(ctx_scope, ()):
                return True
        if restricted:
            return False
    return permission in everywhere


def key_login_binding(
    realm: str, user: str, session_key: bytes, box_key: bytes, signed_at: float
) -> bytes:
    """The bytes an identity key signs to log in: bound to the realm, user and new session."""
    head = f"wart-key-login\0{realm}\0{user}\0".encode()
    return head + session_key + box_key + struct.pack("<d", signed_at)


def mailbox_salt(realm: str, user: str) -> bytes:
    """The argon2id salt of a password user's mailbox key (deterministic: no round trip)."""
    return hashlib.blake2b(f"wart-mailbox\0{realm}\0{user}".encode(), digest_size=16).digest()
