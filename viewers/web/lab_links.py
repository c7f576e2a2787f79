"""The labs a viewer knows, and one router session per lab shared by its users.

Only the viewer's own lab and those an admin listed in ``DATA_DIR/labs.json``
can be logged in to: a registry key is never learnt from whoever answers.
"""

from __future__ import annotations

import json
import logging
import threading
from dataclasses import dataclass
from pathlib import Path

import zenoh

from common.auth import parse_public_key
from common.client.lab_address import AddressError, LabAddress, parse_address
from common.service import close_session
from viewers.web.adapters import (
    LabError,
)
from viewers.web.live_world import WorldWatch

log = logging.getLogger("wart.viewer.live")


@dataclass(frozen=True)
class KnownLab:
    address: LabAddress
    registry_key: bytes
    name: str = ""


def load_labs(path: Path | None, default_realm: str) -> dict[tuple[str, int, str], KnownLab]:
    """Read the admin-kept lab list (``DATA_DIR/labs.json``); bad entries are logged and skipped.

    Format: ``{"labs": [{"address": "wart://host:7447/realm", "registry_key": "HEX",
    "name": "..."}]}``. Only labs listed here (and the viewer's own) can be
    logged in to: a registry key is never learnt from whoever answers.
    """
    if path is None or not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        log.warning("%s is unreadable, no other labs are known: %s", path, exc)
        return {}
    out: dict[tuple[str, int, str], KnownLab] = {}
    entries = data.get("labs", []) if isinstance(data, dict) else []
    for i, entry in enumerate(entries if isinstance(entries, list) else []):
        try:
            if not isinstance(entry, dict):
                raise ValueError("not an object")
            address = parse_address(str(entry["address"]), default_realm=default_realm)
            key = parse_public_key(str(entry["registry_key"]))
            known = KnownLab(address.with_user(None), key, str(entry.get("name", "")))
        except (KeyError, ValueError, AddressError) as exc:
            log.warning("%s: labs[%d] skipped: %s", path, i, exc)
            continue
        out[address.lab_key] = known
    return out


# --- one router's session, shared by everyone logged in through it -----------------------


class LabRouterLink:
    """A Zenoh session to one lab's router, its pinned registry key, and its world watches."""

    def __init__(
        self, address: LabAddress, session: zenoh.Session, registry_key: bytes, *, own: bool
    ) -> None:
        self.address = address
        self.session = session
        self.registry_key = registry_key
        self.own = own  # the viewer's own session: never closed here
        self.users = 0
        self._watches: dict[str, WorldWatch] = {}
        self._lock = threading.Lock()

    def watch(self, world: str) -> WorldWatch:
        with self._lock:
            watch = self._watches.get(world)
            if watch is None or watch.closed:
                watch = WorldWatch(self.session, self.address.realm, world)
                self._watches[world] = watch
            watch.users += 1
        try:
            watch.ready()
        except LabError:
            self.release(watch)
            raise
        return watch

    def release(self, watch: WorldWatch) -> None:
        with self._lock:
            watch.users -= 1
            if watch.users > 0:
                return
            if self._watches.get(watch.world) is watch:
                del self._watches[watch.world]
        watch.close()

    def close(self) -> None:
        with self._lock:
            watches = list(self._watches.values())
            self._watches.clear()
        for watch in watches:
            watch.close()
        if not self.own:
            close_session(self.session)
