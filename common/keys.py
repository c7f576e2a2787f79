"""Every Zenoh key expression of the system, in one place.

Keys are built from a realm and identifiers by the functions below; no other
module writes a key string. The shape follows the Zenoh key-expression rules and
rmw_zenoh's habits: whole chunks (``agent/k1``, never ``agent-k1``), the parts
that vary most at the end, commands and state on distinct suffixes, presence in
its own ``alive`` namespace.

    wart/<realm>/registry/{login,logout,directory,admin,revocations}
    wart/<realm>/alive/<kind>/<id>                         liveliness tokens
    wart/<realm>/user/<name>/inbox                         private messages
    wart/<realm>/ctx/<ctx>/{join,leave,state,request}      context queryables
    wart/<realm>/ctx/<ctx>/{in,events,output}              context pub/sub
    wart/<realm>/world/<world>/{snapshot,edit,map}         world queryables
    wart/<realm>/world/<world>/{frame,sensors}             world frame / all sensors each tick
    wart/<realm>/world/<world>/agent/<agent>/{sensors,cmd,lease}
    wart/<realm>/world/<world>/agent/<agent>/watch        liveliness: someone reads its sensors
    wart/<realm>/runner/<runner>/run                       runner queryable
    wart/<realm>/host/<host>/{spawn,load}                  host queryable / load reports

docs/ARCHITECTURE.md carries the full table (who publishes, who subscribes, the
message type on each key).
"""

from __future__ import annotations

import functools
import inspect
import re
from collections.abc import Callable
from enum import StrEnum
from typing import Any

ROOT = "wart"

# An identifier is one key chunk: no '/', and none of Zenoh's wildcard or
# reserved characters ('*', '$', '?', '#', '@' at the start is the admin space).
_IDENT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$")


class BadIdentifier(ValueError):
    """An identifier cannot be used as a key chunk."""


def check_ident(what: str, value: str) -> str:
    """Return ``value`` if it is a valid identifier, else raise a clear error."""
    if not isinstance(value, str) or not _IDENT.match(value):
        raise BadIdentifier(
            f"{what} {value!r} is not a valid name: use 1 to 64 letters, digits, '_', '-' "
            "or '.', starting with a letter or digit"
        )
    return value


def is_ident(value: str) -> bool:
    return isinstance(value, str) and bool(_IDENT.match(value))


class AliveKind(StrEnum):
    """What a liveliness token announces."""

    ROUTER = "router"
    REGISTRY = "registry"
    USER = "user"
    CONTEXT = "context"
    WORLD = "world"
    RUNNER = "runner"
    VIEWER = "viewer"
    HOST = "host"
    CAMERA = "camera"
    GRADER = "grader"
    LTI = "lti"


def realm_root(realm: str) -> str:
    return f"{ROOT}/{check_ident('realm', realm)}"


def realm_all(realm: str) -> str:
    """Everything of a realm (for tools such as zenoh-cli and the doctor)."""
    return f"{realm_root(realm)}/**"


def wildcard(builder: Callable[..., str], **fixed: Any) -> str:
    """What ``builder`` builds, relative to the realm root, with every free id a ``*``.

    ``wildcard(ctx_join)`` is ``ctx/*/join``; ``wildcard(alive, kind=AliveKind.USER)``
    is ``alive/user/*``. Access-control rules (services/lab/zsecurity.py) are written with
    it, so they name exactly the keys the services use.
    """
    params = [p for p in inspect.signature(builder).parameters if p != "realm"]
    sentinels = {p: f"wildcard{i}" for i, p in enumerate(params) if p not in fixed}
    key = builder(realm=_PATTERN_REALM, **sentinels, **fixed)
    prefix = realm_root(_PATTERN_REALM) + "/"
    if not key.startswith(prefix):
        raise ValueError(f"{builder.__name__} does not build a key of the realm")
    wild = set(sentinels.values())
    return "/".join("*" if chunk in wild else chunk for chunk in key[len(prefix) :].split("/"))


_PATTERN_REALM = "pattern"


# --- registry ---------------------------------------------------------------


def registry_login(realm: str) -> str:
    return f"{realm_root(realm)}/registry/login"


def registry_logout(realm: str) -> str:
    return f"{realm_root(realm)}/registry/logout"


def registry_directory(realm: str) -> str:
    return f"{realm_root(realm)}/registry/directory"


def registry_admin(realm: str) -> str:
    return f"{realm_root(realm)}/registry/admin"


def registry_all(realm: str) -> str:
    """Every registry key (what the registry serves)."""
    return f"{realm_root(realm)}/registry/**"


def registry_revocations(realm: str) -> str:
    """Published by the registry whenever a session is revoked (logout, kick)."""
    return f"{realm_root(realm)}/registry/revocations"


def registry_audit(realm: str) -> str:
    """Admins list the audit trail here (a queryable of the registry)."""
    return f"{realm_root(realm)}/registry/audit"


def registry_report(realm: str) -> str:
    """Services put their privileged actions here, sealed; the registry appends them."""
    return f"{realm_root(realm)}/registry/report"


def registry_lti(realm: str) -> str:
    """The lti service asks here for a launched platform user's account."""
    return f"{realm_root(realm)}/registry/lti"


def registry_twins(realm: str) -> str:
    """Real robots' twins, kept by the registry: runners, teachers and owners ask here."""
    return f"{realm_root(realm)}/registry/twins"


# --- presence ---------------------------------------------------------------


def alive(realm: str, kind: AliveKind, ident: str) -> str:
    return f"{realm_root(realm)}/alive/{AliveKind(kind).value}/{check_ident(str(kind), ident)}"


def alive_of_kind(realm: str, kind: AliveKind) -> str:
    return f"{realm_root(realm)}/alive/{AliveKind(kind).value}/*"


def alive_all(realm: str) -> str:
    return f"{realm_root(realm)}/alive/**"


def parse_alive(realm: str, key: str) -> tuple[AliveKind, str] | None:
    """Split a liveliness key of this realm into (kind, id); None if it is not one."""
    prefix = f"{realm_root(realm)}/alive/"
    if not key.startswith(prefix):
        return None
    parts = key[len(prefix) :].split("/")
    if len(parts) != 2 or not is_ident(parts[1]):
        return None
    try:
        return AliveKind(parts[0]), parts[1]
    except ValueError:
        return None


# --- users ------------------------------------------------------------------


def user_inbox(realm: str, user: str) -> str:
    return f"{realm_root(realm)}/user/{check_ident('user', user)}/inbox"


def user_inbox_all(realm: str) -> str:
    return f"{realm_root(realm)}/user/*/inbox"


# --- contexts (chat rooms, agent contexts) ----------------------------------


def _ctx(realm: str, ctx: str) -> str:
    return f"{realm_root(realm)}/ctx/{check_ident('context', ctx)}"


def ctx_join(realm: str, ctx: str) -> str:
    return f"{_ctx(realm, ctx)}/join"


def ctx_leave(realm: str, ctx: str) -> str:
    return f"{_ctx(realm, ctx)}/leave"


def ctx_state(realm: str, ctx: str) -> str:
    return f"{_ctx(realm, ctx)}/state"


def ctx_request(realm: str, ctx: str) -> str:
    """Queryable for client requests that need an answer (queue, cancel, kick, settings)."""
    return f"{_ctx(realm, ctx)}/request"


def ctx_dryrun(realm: str, ctx: str) -> str:
    """Queryable for dry runs (served on threads of their own: they take seconds)."""
    return f"{_ctx(realm, ctx)}/dryrun"


def ctx_status(realm: str, ctx: str) -> str:
    """Queryable for one request's status (queued, running, ended): for a client that
    missed its request's last event; answered from the context's record, never queued
    behind the requests that change the queues."""
    return f"{_ctx(realm, ctx)}/status"


def ctx_in(realm: str, ctx: str) -> str:
    """Client to context, fire-and-forget (chat lines)."""
    return f"{_ctx(realm, ctx)}/in"


def ctx_events(realm: str, ctx: str) -> str:
    """Context to its members (chat lines, status changes, queue updates, output)."""
    return f"{_ctx(realm, ctx)}/events"


def ctx_output(realm: str, ctx: str) -> str:
    """A running controller's output, from whoever drives (runner, wart control) to its context."""
    return f"{_ctx(realm, ctx)}/output"


# --- worlds (Sim2D engines and Khepera bridges) ------------------------------


def _world(realm: str, world: str) -> str:
    return f"{realm_root(realm)}/world/{check_ident('world', world)}"


def world_estop(realm: str, world: str) -> str:
    """The agent context's emergency stop of every robot of the world (put, sealed)."""
    return f"{_world(realm, world)}/estop"


def world_snapshot(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/snapshot"


def world_edit(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/edit"


def world_map(realm: str, world: str) -> str:
    """Queryable: save the world to a map file, or load another."""
    return f"{_world(realm, world)}/map"


def world_robots(realm: str, world: str) -> str:
    """Queryable: the robot types a world knows (list, a file's text) and saving one."""
    return f"{_world(realm, world)}/robots"


def world_frame(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/frame"


def world_layout(realm: str, world: str) -> str:
    """The world's layout number, put when its rows change (WorldLayout): a frame says it
    each tick, but only to those who watch; this says it to those who do not."""
    return f"{_world(realm, world)}/layout"


def world_sensors(realm: str, world: str) -> str:
    """Every agent's sensor readings in one message per tick (SensorBatch)."""
    return f"{_world(realm, world)}/sensors"


def world_samples(realm: str, world: str) -> str:
    """The leased agents' SensorSamples in one message per tick (SampleBundle)."""
    return f"{_world(realm, world)}/samples"


def world_commands(realm: str, world: str) -> str:
    """Several agents' sealed or MACed commands in one message (CommandBundle)."""
    return f"{_world(realm, world)}/cmds"


def world_tracked(realm: str, world: str) -> str:
    """The robots' poses an overhead camera tracked, one message per frame (TrackedPoses)."""
    return f"{_world(realm, world)}/tracked"


def _camera(realm: str, world: str, camera: str) -> str:
    return f"{_world(realm, world)}/camera/{check_ident('camera', camera)}"


def camera_frame(realm: str, world: str, camera: str) -> str:
    """One camera's newest compressed frame over a world's arena (CameraFrame)."""
    return f"{_camera(realm, world, camera)}/image"


def camera_floor(realm: str, world: str, camera: str) -> str:
    """The arena's floor as the camera sees it, rectified to arena mm (CameraFrame)."""
    return f"{_camera(realm, world, camera)}/floor"


def camera_status(realm: str, world: str, camera: str) -> str:
    """Whether a camera sees its arena, and why not (CameraStatus), on change and every 2 s."""
    return f"{_camera(realm, world, camera)}/status"


def camera_all(realm: str, world: str) -> str:
    """Every camera's frames and status over one world."""
    return f"{_world(realm, world)}/camera/**"


def _agent(realm: str, world: str, agent: str) -> str:
    return f"{_world(realm, world)}/agent/{check_ident('agent', agent)}"


def agent_sensors(realm: str, world: str, agent: str) -> str:
    return f"{_agent(realm, world, agent)}/sensors"


def agent_sensors_all(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/agent/*/sensors"


def agent_watch(realm: str, world: str, agent: str) -> str:
    """Liveliness token of a subscriber to ``agent_sensors``: the world's cue to publish them.

    A world of more robots than it declares publishers for up front (the
    engine's ``--streams-up-front``) declares an agent's publisher only once
    the agent is watched (a token here) or leased.
    """
    return f"{_agent(realm, world, agent)}/watch"


def agent_watch_all(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/agent/*/watch"


@functools.lru_cache(maxsize=4096)
def agent_cmd(realm: str, world: str, agent: str) -> str:
    """Cached: worlds and links build it for every command, 50 times a second per robot
    (a bad name raises BadIdentifier and is not cached)."""
    return f"{_agent(realm, world, agent)}/cmd"


def agent_cmd_all(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/agent/*/cmd"


def agent_lease(realm: str, world: str, agent: str) -> str:
    """The agent's current lease, published by the agent context that owns its queue."""
    return f"{_agent(realm, world, agent)}/lease"


def agent_lease_all(realm: str, world: str) -> str:
    return f"{_world(realm, world)}/agent/*/lease"


def parse_agent_key(realm: str, world: str, key: str) -> str | None:
    """The agent id from any ``.../world/<world>/agent/<agent>/<suffix>`` key."""
    prefix = f"{_world(realm, world)}/agent/"
    if not key.startswith(prefix):
        return None
    parts = key[len(prefix) :].split("/")
    if len(parts) != 2 or not is_ident(parts[0]):
        return None
    return parts[0]


# --- runners and hosts -------------------------------------------------------


def runner_run(realm: str, runner: str) -> str:
    return f"{realm_root(realm)}/runner/{check_ident('runner', runner)}/run"


def runner_dryrun(realm: str, runner: str) -> str:
    """Dry runs of controllers in a private world (beside ``run``: never delays a slot)."""
    return f"{realm_root(realm)}/runner/{check_ident('runner', runner)}/dryrun"


def runner_episode(realm: str, runner: str) -> str:
    """Graded episodes of a submission in a private world (the grader asks; beside ``run``)."""
    return f"{realm_root(realm)}/runner/{check_ident('runner', runner)}/episode"


def runner_heat(realm: str, runner: str) -> str:
    """A competition's heat of several entries in one world (the grader asks)."""
    return f"{realm_root(realm)}/runner/{check_ident('runner', runner)}/heat"


def runner_grade(realm: str, runner: str) -> str:
    """A teacher's grader function on a real attempt's data (the grader asks; beside
    ``episode``, which runs it after a simulated episode itself)."""
    return f"{realm_root(realm)}/runner/{check_ident('runner', runner)}/grade"


def grader_request(realm: str, grader: str) -> str:
    """Submissions, their results and leaderboards (students and teachers ask the grader)."""
    return f"{realm_root(realm)}/grader/{check_ident('grader', grader)}/request"


def grader_standings(realm: str, grader: str, competition: str) -> str:
    """A competition's standings, published (sealed) by the grader as each heat ends."""
    g = check_ident("grader", grader)
    return f"{realm_root(realm)}/grader/{g}/competition/{check_ident('competition', competition)}"


def grader_graded(realm: str, grader: str) -> str:
    """Each submission as it is graded (sealed by the grader; the lti service passes it back)."""
    return f"{realm_root(realm)}/grader/{check_ident('grader', grader)}/graded"


def grader_standings_all(realm: str, grader: str) -> str:
    return f"{realm_root(realm)}/grader/{check_ident('grader', grader)}/competition/*"


def grader_changed(realm: str, grader: str, course: str) -> str:
    """A submission of the course changed state (sealed by the grader; no score, no name)."""
    g = check_ident("grader", grader)
    return f"{realm_root(realm)}/grader/{g}/changed/{check_ident('course', course)}"


def grader_changed_all(realm: str, grader: str) -> str:
    return f"{realm_root(realm)}/grader/{check_ident('grader', grader)}/changed/*"


def grader_queue(realm: str, grader: str) -> str:
    """The grader's queue depth, put every few seconds (a cluster's host scales runners on it)."""
    return f"{realm_root(realm)}/grader/{check_ident('grader', grader)}/queue"


def grader_queue_all(realm: str) -> str:
    return f"{realm_root(realm)}/grader/*/queue"


def host_spawn(realm: str, host: str) -> str:
    return f"{realm_root(realm)}/host/{check_ident('host', host)}/spawn"


def host_load(realm: str, host: str) -> str:
    return f"{realm_root(realm)}/host/{check_ident('host', host)}/load"


def host_load_all(realm: str) -> str:
    return f"{realm_root(realm)}/host/*/load"


# --- Zenoh's own admin space (routers describe themselves there) ----------------


def router_admin(zid: str) -> str:
    """One router's admin view (its locators, sessions and links)."""
    return f"@/{zid}/router"


def routers_admin_all() -> str:
    return "@/*/router"


def admin_space_all() -> str:
    """The whole admin space (access-control rules reserve it to admins)."""
    return "@/**"
