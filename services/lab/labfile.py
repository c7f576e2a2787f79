"""The lab file: one TOML file that describes a lab spread over several hosts.

``deploy/lab.example.toml`` is the documented example. Every host of the lab
reads the same file (``wart host --lab FILE --name HOST``); ``wart certs lab``
issues every certificate it names; ``wart doctor --lab FILE`` knows where the
routers should be. Loading validates everything and raises one
:class:`LabFileError` naming the field (``hosts[1].services[0].world``) and
what is wrong, before anything starts.

Relative paths in the file are relative to the file's directory.
"""

from __future__ import annotations

import ipaddress
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.keys import is_ident
from common.sim2d.drives import DRIVES

# What a host can run: the fields each kind requires, then the optional ones.
# ``agent`` is an agent context for a world the lab file names (a bridge's
# real robots, usually); every engine gets its own when [arena].agent is true.
SERVICE_KINDS: dict[str, tuple[str, ...]] = {
    "registry": (),
    "chat": ("name",),
    "engine": ("world", "map"),
    "bridge": ("world",),
    "agent": ("name", "world"),
    "viewer": (),
    "runner": ("name",),
    # The grader: on the registry's host (it shares its database).
    "grader": (),
    # A camera over a real arena (wart camera): its world and what it captures from.
    "camera": ("world", "source"),
    # The LTI 1.3 tool (services/lti/): its platforms file (TOML, docs/COURSES.md).
    "lti": ("platforms",),
}
OPTIONAL_FIELDS: dict[str, tuple[str, ...]] = {
    "registry": ("server_name",),
    # owner: the user who manages the room or context (default: its own account).
    "chat": ("title", "owner"),
    # An engine is an arena: ``context`` names its agent context (default: the
    # world's name); ``login`` gives the engine an account, so agent contexts
    # grant it MAC leases (commands checked in µs instead of an Ed25519 verify).
    # ``drive``: how its robots are driven (wart engine --drive; "discs" for swarms).
    "engine": ("seed", "robots", "context", "title", "owner", "login", "drive"),
    # ports: PATH=ID@X,Y,DEG as for `wart bridge --port`; emulate: a map name
    # whose first robot an emulated Khepera plays (a lab without hardware).
    # camera (with emulate, default true): a synthetic camera over the emulated arena.
    "bridge": ("ports", "emulate", "login", "camera"),
    "agent": ("title", "runner", "slot_seconds", "owner"),
    # name: the viewer's id in the lab (default: its host's name).
    "viewer": ("name", "http_port", "http_host"),
    # min_replicas, max_replicas: a runner in a cluster scaled on the grader's queue
    # (services/lab/kube/runner_scale.py): per_replica submissions waiting per pod,
    # cooldown_s before it scales down.
    "runner": ("min_replicas", "max_replicas", "per_replica", "cooldown_s"),
    # workers: submissions graded at once (wart grader --workers); with a scaled runner,
    # raise it with max_replicas, or the pods beyond it get no work.
    "grader": ("name", "workers"),
    # calibration: a file made by `wart camera calibrate` (default: the state dir's,
    # made from the reference markers once they are in view).
    "camera": ("name", "calibration", "fps"),
    "lti": ("name", "http_port", "http_host"),
}

DEFAULT_RUNNER = "runner"  # what agent contexts name when the lab file has no runner


class LabFileError(ValueError):
    """The lab file is wrong; the message names the field."""


@dataclass(frozen=True)
class RunnerScale:
    """How a runner's Deployment is scaled on the grader's queue depth."""

    min_replicas: int
    max_replicas: int
    per_replica: int = 2  # submissions graded at once by one runner pod
    cooldown_s: float = 300.0  # the depth low this long before replicas are taken away


@dataclass(frozen=True)
class ServiceEntry:
    kind: str
    params: Mapping[str, Any]

    @property
    def ident(self) -> str:
        """The name that tells this service apart on its host (a room, a world...)."""
        return str(self.params.get("name") or self.params.get("world") or self.kind)

    @property
    def scale(self) -> RunnerScale | None:
        """A runner's scaling on the grader's queue (None: one replica, scaled by hand)."""
        found = self.params.get("scale")
        return found if isinstance(found, RunnerScale) else None


@dataclass(frozen=True)
class HostEntry:
    name: str
    address: str
    port: int
    names: tuple[str, ...]  # extra DNS names for its certificates
    connect: tuple[str, ...]  # the hosts whose routers this host's router connects to
    services: tuple[ServiceEntry, ...]
    arenas: bool  # whether arenas may be placed here

    @property
    def endpoint(self) -> str:
        """Where other hosts reach this host's router."""
        host = f"[{self.address}]" if ":" in self.address else self.address
        return f"tls/{host}:{self.port}"

    @property
    def local_endpoint(self) -> str:
        return f"tls/127.0.0.1:{self.port}"

    def kinds(self) -> set[str]:
        return {s.kind for s in self.services}


@dataclass(frozen=True)
class Security:
    pki: Path  # see services/lab/certs.py and docs/DEPLOY.md for the layout
    acl: bool  # access-control rules on every router, default deny
    student_names: tuple[str, ...]  # certificate CNs of people's tools (chat, control, arena)
    admin_names: tuple[str, ...]  # certificate CNs of operators' tools (doctor)


@dataclass(frozen=True)
class Limits:
    max_arenas_per_host: int
    max_robots_per_arena: int
    max_cpu_percent: float  # a host busier than this takes no new arena
    min_free_memory_mb: int
    load_period_s: float


@dataclass(frozen=True)
class ArenaSettings:
    """What every arena is: an engine, and its agent context unless ``agent`` is false.

    Data, not command lines: the processes themselves are built by
    services/lab/wiring.py, the one place that writes each kind's command line.
    """

    agent: bool = True  # false: arenas without an agent context (engines alone)
    slot_seconds: float | None = None  # their queues' slot length (None: the context's default)


@dataclass(frozen=True)
class LabFile:
    path: Path
    realm: str
    lease_ms: int  # Zenoh transport lease: how soon a silent host is taken as gone
    hosts: tuple[HostEntry, ...]
    security: Security
    limits: Limits
    arena: ArenaSettings
    state_dir: Path | None = None
    maps_dir: Path = field(default_factory=lambda: Path("maps"))

    def host(self, name: str) -> HostEntry:
        for host in self.hosts:
            if host.name == name:
                return host
        known = ", ".join(h.name for h in self.hosts)
        raise LabFileError(f"{self.path}: no host named {name!r} (hosts: {known})")

    def registry_host(self) -> HostEntry:
        return next(h for h in self.hosts if "registry" in h.kinds())

    def hosts_dir(self, host: str) -> Path:
        return self.security.pki / host

    def runner_for(self, host: str) -> str:
        """The runner an agent context on ``host`` uses by default: its host's, else the lab's."""
        runners = [
            (h.name != host, s.ident)
            for h in self.hosts
            for s in h.services
            if s.kind == "runner" and s.scale is None  # a scaled runner's pods have own names
        ]
        return min(runners)[1] if runners else DEFAULT_RUNNER


# --- parsing ----------------------------------------------------------------------


def _type(where: str, value: Any, expected: type | tuple[type, ...], what: str) -> Any:
    # bool is an int in Python; a port of `true` is an error, not 1.
    if isinstance(value, bool) and bool not in (
        expected if isinstance(expected, tuple) else (expected,)
    ):
        raise LabFileError(f"{where}: expected {what}, got a boolean")
    if not isinstance(value, expected):
        raise LabFileError(f"{where}: expected {what}, got {type(value).__name__} {value!r}")
    return value


def _table(where: str, value: Any) -> dict[str, Any]:
    return dict(_type(where, value, dict, "a table"))


def _unknown(where: str, table: Mapping[str, Any], allowed: Sequence[str]) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise LabFileError(
            f"{where}: unknown field{'s' if len(extra) > 1 else ''} {', '.join(extra)} "
            f"(allowed: {', '.join(allowed)})"
        )


def _ident(where: str, value: Any) -> str:
    _type(where, value, str, "a name")
    if not is_ident(value):
        raise LabFileError(
            f"{where}: {value!r} is not a valid name (1 to 64 letters, digits, '_', '-', '.')"
        )
    return str(value)


def _int(where: str, value: Any, low: int, high: int) -> int:
    _type(where, value, int, "an integer")
    if not low <= value <= high:
        raise LabFileError(f"{where}: {value} is out of range ({low} to {high})")
    return int(value)


def _number(where: str, value: Any, low: float, high: float) -> float:
    _type(where, value, (int, float), "a number")
    if not low <= value <= high:
        raise LabFileError(f"{where}: {value} is out of range ({low} to {high})")
    return float(value)


def _strings(where: str, value: Any) -> tuple[str, ...]:
    _type(where, value, list, "a list of strings")
    for i, item in enumerate(value):
        _type(f"{where}[{i}]", item, str, "a string")
    return tuple(value)


def _address(where: str, value: Any) -> str:
    _type(where, value, str, "an IP address or host name")
    try:
        ipaddress.ip_address(value)
        return str(value)
    except ValueError:
        pass
    labels = value.split(".")
    if (
        not value
        or len(value) > 253
        or not all(
            label and len(label) <= 63 and label.replace("-", "").isalnum() for label in labels
        )
    ):
        raise LabFileError(f"{where}: {value!r} is neither an IP address nor a host name")
    return str(value)


def service_entry(where: str, raw: Any) -> ServiceEntry:
    """One ``[[hosts.services]]`` table, validated; ``where`` names it in errors."""
    table = _table(where, raw)
    kind = table.get("kind")
    if kind not in SERVICE_KINDS:
        raise LabFileError(
            f"{where}.kind: {kind!r} is not a service kind (one of {', '.join(SERVICE_KINDS)})"
        )
    required, optional = SERVICE_KINDS[kind], OPTIONAL_FIELDS[kind]
    _unknown(where, table, ("kind", *required, *optional))
    for name in required:
        if name not in table:
            raise LabFileError(f"{where}: a {kind} service needs '{name}'")
    params: dict[str, Any] = {}
    for name in ("name", "world", "runner", "owner", "context"):
        if name in table:
            params[name] = _ident(f"{where}.{name}", table[name])
    for name in ("map", "title", "server_name", "http_host", "source", "calibration", "platforms"):
        if name in table:
            params[name] = _type(f"{where}.{name}", table[name], str, "a string")
    if "seed" in table:
        params["seed"] = _int(f"{where}.seed", table["seed"], 0, 2**31 - 1)
    if "robots" in table:
        params["robots"] = _int(f"{where}.robots", table["robots"], 1, 1000)
    if "http_port" in table:
        params["http_port"] = _int(f"{where}.http_port", table["http_port"], 1, 65535)
    if "ports" in table:
        params["ports"] = _strings(f"{where}.ports", table["ports"])
    if "fps" in table:
        params["fps"] = _number(f"{where}.fps", table["fps"], 1, 30)
    if "camera" in table:
        params["camera"] = bool(_type(f"{where}.camera", table["camera"], bool, "true or false"))
    if "login" in table:
        params["login"] = bool(_type(f"{where}.login", table["login"], bool, "true or false"))
    if "emulate" in table:
        params["emulate"] = _ident(f"{where}.emulate", table["emulate"])
    if "drive" in table:
        drive = _type(f"{where}.drive", table["drive"], str, "a string")
        if drive not in DRIVES:
            raise LabFileError(
                f"{where}.drive: {drive!r} is not a drive (one of {', '.join(DRIVES)})"
            )
        params["drive"] = drive
    if "slot_seconds" in table:
        params["slot_seconds"] = _number(f"{where}.slot_seconds", table["slot_seconds"], 1, 3600)
    if "workers" in table:
        params["workers"] = _int(f"{where}.workers", table["workers"], 1, 64)
    if kind == "runner" and ("min_replicas" in table or "max_replicas" in table):
        params["scale"] = _runner_scale(where, table)
    if kind == "bridge" and not (params.get("ports") or params.get("emulate")):
        raise LabFileError(f"{where}: a bridge needs 'ports' (its robots) or 'emulate' (a map)")
    return ServiceEntry(kind=kind, params=params)


def _runner_scale(where: str, table: Mapping[str, Any]) -> RunnerScale:
    for name in ("min_replicas", "max_replicas"):
        if name not in table:
            raise LabFileError(f"{where}: a scaled runner needs both min_replicas and max_replicas")
    low = _int(f"{where}.min_replicas", table["min_replicas"], 0, 100)
    high = _int(f"{where}.max_replicas", table["max_replicas"], 1, 100)
    if low > high:
        raise LabFileError(f"{where}: min_replicas ({low}) is above max_replicas ({high})")
    return RunnerScale(
        low,
        high,
        _int(f"{where}.per_replica", table.get("per_replica", 2), 1, 100),
        _number(f"{where}.cooldown_s", table.get("cooldown_s", 300.0), 0, 86400),
    )


def parse(data: Mapping[str, Any], path: Path) -> LabFile:
    """Validate a decoded lab file; raises LabFileError naming the field."""
    base = path.parent
    top = dict(data)
    _unknown(
        str(path),
        top,
        (
            "realm",
            "lease_ms",
            "port",
            "state_dir",
            "maps_dir",
            "security",
            "limits",
            "arena",
            "hosts",
        ),
    )
    if "realm" not in top:
        raise LabFileError(f"{path}: 'realm' is missing (the lab's name, e.g. realm = \"lab\")")
    realm = _ident("realm", top["realm"])
    lease_ms = _int("lease_ms", top.get("lease_ms", 10_000), 500, 600_000)
    default_port = _int("port", top.get("port", 7447), 1, 65535)
    state_dir = (
        base / _type("state_dir", top["state_dir"], str, "a path") if "state_dir" in top else None
    )
    maps_dir = base / _type("maps_dir", top.get("maps_dir", "maps"), str, "a path")

    sec = _table("security", top.get("security", {}))
    _unknown("security", sec, ("pki", "acl", "student_names", "admin_names"))
    if "pki" not in sec:
        raise LabFileError("security.pki: missing (the directory `wart certs` writes)")
    security = Security(
        pki=base / _type("security.pki", sec["pki"], str, "a path"),
        acl=bool(_type("security.acl", sec.get("acl", True), bool, "true or false")),
        student_names=tuple(
            _ident(f"security.student_names[{i}]", n)
            for i, n in enumerate(
                _strings("security.student_names", sec.get("student_names", ["student"]))
            )
        ),
        admin_names=tuple(
            _ident(f"security.admin_names[{i}]", n)
            for i, n in enumerate(
                _strings("security.admin_names", sec.get("admin_names", ["admin"]))
            )
        ),
    )

    lim = _table("limits", top.get("limits", {}))
    allowed_limits = (
        "max_arenas_per_host",
        "max_robots_per_arena",
        "max_cpu_percent",
        "min_free_memory_mb",
        "load_period_s",
    )
    _unknown("limits", lim, allowed_limits)
    limits = Limits(
        max_arenas_per_host=_int(
            "limits.max_arenas_per_host", lim.get("max_arenas_per_host", 4), 0, 1000
        ),
        max_robots_per_arena=_int(
            "limits.max_robots_per_arena", lim.get("max_robots_per_arena", 50), 1, 1000
        ),
        max_cpu_percent=_number(
            "limits.max_cpu_percent", lim.get("max_cpu_percent", 85.0), 1.0, 100.0
        ),
        min_free_memory_mb=_int(
            "limits.min_free_memory_mb", lim.get("min_free_memory_mb", 256), 0, 10**7
        ),
        load_period_s=_number("limits.load_period_s", lim.get("load_period_s", 2.0), 0.1, 3600.0),
    )

    arena = _table("arena", top.get("arena", {}))
    for gone in ("engine", "agent"):
        if isinstance(arena.get(gone), list):
            # The command-line templates of older lab files: every process's command line
            # is now written once, in services/lab/wiring.py.
            raise LabFileError(
                f"arena.{gone}: command templates are no longer read; write "
                "agent = true or false (arenas with or without an agent context) and, "
                "for short queue slots, slot_seconds = N"
            )
    _unknown("arena", arena, ("agent", "slot_seconds"))
    settings = ArenaSettings(
        agent=bool(_type("arena.agent", arena.get("agent", True), bool, "true or false")),
        slot_seconds=_number("arena.slot_seconds", arena["slot_seconds"], 1, 3600)
        if "slot_seconds" in arena
        else None,
    )

    raw_hosts = _type("hosts", top.get("hosts", []), list, "a list of [[hosts]] tables")
    if not raw_hosts:
        raise LabFileError(f"{path}: no [[hosts]]: a lab needs at least one host")
    hosts: list[HostEntry] = []
    seen: dict[str, str] = {}
    for i, raw in enumerate(raw_hosts):
        where = f"hosts[{i}]"
        table = _table(where, raw)
        _unknown(
            where, table, ("name", "address", "port", "names", "connect", "services", "arenas")
        )
        for required in ("name", "address"):
            if required not in table:
                raise LabFileError(f"{where}: '{required}' is missing")
        name = _ident(f"{where}.name", table["name"])
        if name in seen:
            raise LabFileError(f"{where}.name: host {name!r} is listed twice")
        address = _address(f"{where}.address", table["address"])
        port = _int(f"{where}.port", table.get("port", default_port), 1, 65535)
        if (address, port) in {(h.address, h.port) for h in hosts}:
            raise LabFileError(f"{where}: {address}:{port} is already another host's router")
        names = tuple(
            _address(f"{where}.names[{j}]", n)
            for j, n in enumerate(_strings(f"{where}.names", table.get("names", [])))
        )
        if "connect" in table:
            connect = _strings(f"{where}.connect", table["connect"])
        else:
            # By default a host's router connects to every host listed before
            # it, so adding a host at the end changes nothing on the others.
            connect = tuple(h.name for h in hosts)
        services = tuple(
            service_entry(f"{where}.services[{j}]", s)
            for j, s in enumerate(
                _type(f"{where}.services", table.get("services", []), list, "a list")
            )
        )
        idents: set[tuple[str, str]] = set()
        for j, svc in enumerate(services):
            if (svc.kind, svc.ident) in idents:
                raise LabFileError(f"{where}.services[{j}]: a second {svc.kind} {svc.ident!r}")
            idents.add((svc.kind, svc.ident))
        arenas = bool(_type(f"{where}.arenas", table.get("arenas", True), bool, "true or false"))
        seen[name] = where
        hosts.append(HostEntry(name, address, port, names, connect, services, arenas))

    names_set = {h.name for h in hosts}
    for i, host in enumerate(hosts):
        for j, target in enumerate(host.connect):
            if target not in names_set:
                raise LabFileError(f"hosts[{i}].connect[{j}]: no host named {target!r}")
            if target == host.name:
                raise LabFileError(f"hosts[{i}].connect[{j}]: a host does not connect to itself")
    registries = [h.name for h in hosts if "registry" in h.kinds()]
    if len(registries) != 1:
        raise LabFileError(
            f"hosts: exactly one host runs the registry (found {len(registries)}: "
            f"{', '.join(registries) or 'none'})"
        )
    worlds: dict[str, str] = {}
    rooms: dict[str, str] = {}  # contexts: chat rooms, agent contexts (and arenas' below)
    runners: dict[str, str] = {}
    for host in hosts:
        for svc in host.services:
            table_by_kind = (
                worlds
                if svc.kind in ("engine", "bridge")
                else rooms
                if svc.kind in ("chat", "agent")
                else runners
                if svc.kind == "runner"
                else None
            )
            if table_by_kind is None:
                continue
            if svc.ident in table_by_kind:
                raise LabFileError(
                    f"hosts: {svc.kind} {svc.ident!r} runs on both {table_by_kind[svc.ident]} and "
                    f"{host.name}: names are lab-wide"
                )
            table_by_kind[svc.ident] = host.name
    if settings.agent:
        # An engine's agent context is named after its world: it shares the
        # context names with chat rooms and the lab file's agent contexts.
        for world, where_world in worlds.items():
            if world in rooms and any(
                s.kind == "engine" and s.ident == world for h in hosts for s in h.services
            ):
                raise LabFileError(
                    f"hosts: engine {world!r} on {where_world} gets an agent context named "
                    f"{world!r} from [arena].agent, and a context on {rooms[world]} has that name"
                )
    known_runners = set(runners)
    scaled = {s.ident for h in hosts for s in h.services if s.scale is not None}
    for i, host in enumerate(hosts):
        for j, svc in enumerate(host.services):
            runner = svc.params.get("runner")
            if runner is not None and runner not in known_runners:
                raise LabFileError(
                    f"hosts[{i}].services[{j}].runner: no runner named {runner!r} in the lab "
                    f"({', '.join(sorted(known_runners)) or 'none'})"
                )
            if runner is not None and runner in scaled:
                raise LabFileError(
                    f"hosts[{i}].services[{j}].runner: runner {runner!r} is scaled on the "
                    "grader's queue (its pods take names of their own): name a runner without "
                    "min_replicas and max_replicas"
                )
    return LabFile(
        path=path,
        realm=realm,
        lease_ms=lease_ms,
        hosts=tuple(hosts),
        security=security,
        limits=limits,
        arena=settings,
        state_dir=state_dir,
        maps_dir=maps_dir,
    )


def load(path: Path) -> LabFile:
    """Read and validate a lab file."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise LabFileError(f"cannot read the lab file {path}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise LabFileError(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise LabFileError(f"{path}: not valid TOML: {exc}") from None
    return parse(data, path.resolve())
