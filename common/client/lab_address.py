"""The address bar: ``wart://user@host:port/realm[/context]`` and friends (thesis 7.3.1).

Pure parsing, no I/O, so it is unit-tested on its own. What a person may type:

    wart://ana@lab.example.org:7447/lab/arena   everything spelled out
    lab.example.org                             a plain host: default port and realm
    ana@10.0.0.5                                a user and a host
    10.0.0.5:7448/physics                       a port and a realm
    [fe80::1]:7447/lab                          an IPv6 host in brackets

Missing parts take the defaults given to :func:`parse_address` (port 7447, the
viewer's own realm). :class:`SavedConnections` keeps each user's saved and
recent addresses in one JSON file under the viewer's data directory.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

from common.keys import is_ident
from common.zconfig import DEFAULT_PORT, DEFAULT_REALM

SCHEME = "wart://"
MAX_ADDRESS = 300  # longer than any sane address; refuse before parsing

# RFC 1123 host names: dot-separated labels of letters, digits and inner hyphens.
_HOST_LABEL = re.compile(r"^(?!-)[A-Za-z0-9-]{1,63}(?<!-)$")


class AddressError(ValueError):
    """An address the bar cannot use; the message is shown to the person as is."""


@dataclass(frozen=True)
class LabAddress:
    """Where a lab is, who to log in as, and optionally which context to open."""

    host: str
    port: int = DEFAULT_PORT
    realm: str = DEFAULT_REALM
    user: str | None = None
    context: str | None = None

    @property
    def lab_key(self) -> tuple[str, int, str]:
        """Identity of the lab (two addresses with the same key are the same lab)."""
        return (self.host.lower(), self.port, self.realm)

    @property
    def endpoint(self) -> str:
        """The Zenoh endpoint of the lab's router."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp/{host}:{self.port}"

    @property
    def label(self) -> str:
        """Short name for a tab: ``realm@host`` (the port only when not the default)."""
        port = "" if self.port == DEFAULT_PORT else f":{self.port}"
        return f"{self.realm}@{self.host}{port}"

    def url(self, *, with_user: bool = True, with_context: bool = True) -> str:
        """The canonical spelling, which :func:`parse_address` reads back unchanged."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        user = f"{self.user}@" if with_user and self.user else ""
        ctx = f"/{self.context}" if with_context and self.context else ""
        return f"{SCHEME}{user}{host}:{self.port}/{self.realm}{ctx}"

    def with_user(self, user: str | None) -> LabAddress:
        return LabAddress(self.host, self.port, self.realm, user, self.context)


def _check_host(host: str) -> str:
    if not host:
        raise AddressError("the address has no host name: type e.g. lab.example.org")
    try:
        return str(ipaddress.ip_address(host))
    except ValueError:
        pass
    labels = host.rstrip(".").split(".")
    if len(host) > 253 or not all(_HOST_LABEL.match(label) for label in labels):
        raise AddressError(f"{host!r} is not a host name or an IP address")
    return host.rstrip(".").lower()


def _check_name(what: str, value: str) -> str:
    if not is_ident(value):
        raise AddressError(
            f"{what} {value!r} is not a valid name: use letters, digits, '_', '-' or '.', "
            "starting with a letter or digit"
        )
    return value


def parse_address(
    text: str, *, default_port: int = DEFAULT_PORT, default_realm: str = DEFAULT_REALM
) -> LabAddress:
    """Read what was typed in the address bar; :class:`AddressError` says what is wrong."""
    text = (text or "").strip()
    if not text:
        raise AddressError("type an address, e.g. wart://you@lab.example.org/lab")
    if len(text) > MAX_ADDRESS:
        raise AddressError(f"the address is too long (over {MAX_ADDRESS} characters)")
    if any(ch.isspace() for ch in text):
        raise AddressError("an address has no spaces")
    if "://" in text:
        scheme, _, text = text.partition("://")
        if scheme.lower() != "wart":
            raise AddressError(f"only wart:// addresses are supported, not {scheme}://")
    authority, _, path = text.partition("/")
    user: str | None = None
    if "@" in authority:
        user, _, authority = authority.rpartition("@")
        user = _check_name("user name", user)
    port = default_port
    if authority.startswith("["):  # [IPv6] or [IPv6]:port
        close = authority.find("]")
        if close < 0:
            raise AddressError("an IPv6 address needs a closing ']'")
        host, rest = authority[1:close], authority[close + 1 :]
        if rest and not rest.startswith(":"):
            raise AddressError(f"unexpected {rest!r} after the IPv6 address")
        port_text = rest[1:] if rest else ""
        try:
            ipaddress.IPv6Address(host)
        except ValueError as exc:
            raise AddressError(f"{host!r} is not an IPv6 address") from exc
    else:
        host, colon, port_text = authority.partition(":")
        if colon and not port_text:
            raise AddressError("a ':' after the host must be followed by a port number")
    if port_text:
        if not port_text.isdigit() or not 0 < int(port_text) < 65536:
            raise AddressError(f"port {port_text!r} is not a number from 1 to 65535")
        port = int(port_text)
    host = _check_host(host)
    parts = [p for p in path.split("/") if p] if path else []
    if len(parts) > 2:
        raise AddressError("an address ends at /realm/context; there is more after it")
    realm = _check_name("realm", parts[0]) if parts else default_realm
    context = _check_name("context", parts[1]) if len(parts) > 1 else None
    return LabAddress(host=host, port=port, realm=realm, user=user, context=context)


# --- saved connections ---------------------------------------------------------------

MAX_RECENT = 10
MAX_SAVED = 30


class SavedConnections:
    """Each user's saved (starred) and recent addresses, kept in one JSON file.

    Server-side and per user (the name they logged in with), so a shared lab
    computer's browser does not show one student's list to the next. Writes go
    through a temporary file and a rename: a crash never leaves half a file.
    """

    def __init__(self, path: Path | None) -> None:
        self._path = path
        self._lock = threading.Lock()
        self._data: dict[str, dict[str, list[str]]] = {}
        if path is not None and path.exists():
            try:
                raw = json.loads(path.read_text())
            except (OSError, ValueError):
                raw = {}  # an unreadable file starts an empty list, never a crash
            if isinstance(raw, dict):
                for user, lists in raw.items():
                    if is_ident(user) and isinstance(lists, dict):
                        self._data[user] = {
                            kind: [a for a in lists.get(kind, []) if isinstance(a, str)]
                            for kind in ("saved", "recent")
                        }

    def for_user(self, user: str) -> list[str]:
        """Saved addresses first, then recent ones not already saved."""
        with self._lock:
            lists = self._data.get(user, {})
            saved = list(lists.get("saved", []))
            return saved + [a for a in lists.get("recent", []) if a not in saved]

    def add_recent(self, user: str, address: LabAddress) -> None:
        self._add(user, "recent", address.url(), MAX_RECENT)

    def save(self, user: str, address: LabAddress) -> None:
        self._add(user, "saved", address.url(), MAX_SAVED)

    def forget(self, user: str, url: str) -> None:
        with self._lock:
            lists = self._data.get(user)
            if lists:
                for kind in lists:
                    lists[kind] = [a for a in lists[kind] if a != url]
            self._write()

    def _add(self, user: str, kind: str, url: str, limit: int) -> None:
        with self._lock:
            lists = self._data.setdefault(user, {"saved": [], "recent": []})
            entries = [url] + [a for a in lists.get(kind, []) if a != url]
            lists[kind] = entries[:limit]
            self._write()

    def _write(self) -> None:
        if self._path is None:
            return
        self._path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self._path.parent, prefix=".connections.")
        with os.fdopen(fd, "w") as out:
            json.dump(self._data, out, indent=1, sort_keys=True)
        os.replace(tmp, self._path)


def complete(prefix: str, candidates: list[str]) -> list[str]:
    """Candidates matching what is typed so far (prefix first, then substring)."""
    needle = prefix.strip().lower()
    if not needle:
        return list(candidates)
    bare = needle.removeprefix(SCHEME)
    starts = [c for c in candidates if c.lower().removeprefix(SCHEME).startswith(bare)]
    inside = [c for c in candidates if bare in c.lower() and c not in starts]
    return starts + inside
