"""A page that goes away keeps its lab session for a grace period: a reload loses nothing.

Students reload, close a laptop's lid and lose Wi-Fi. When a browser's page
goes, each lab it was logged in to is *parked* here instead of logged out: the
lab session stays (its contexts joined, its runs and their slots going on), the
lab's events for it are kept, and the tabs' state (editor buffer, chosen robot,
output, chat lines, the arena in view) is remembered. A page that comes back
within the grace with the same saved login (the cookie of saved_login.py, whose
resume token is the parked session's own) takes the session back: its tabs are
drawn again as they were, and the events kept meanwhile are played into them.
No second login happens, so the registry and the contexts see nothing.

Past the grace the session ends as a closed page's always did, but its rooms
are told why ("the page was closed for more than 2 min"), and a run it held
ends with those words. A grace of 0 turns parking off.
"""

from __future__ import annotations

import hmac
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from viewers.web.adapters import LabConnection, LabError, LabEvent, LoginUnavailable
from viewers.web.chat_panel import PanelMemory
from viewers.web.handover import HandedOver

log = logging.getLogger("wart.viewer.parking")

DEFAULT_GRACE_S = 120.0
MAX_KEPT_EVENTS = 5000  # a busy arena's output for two minutes; older events are dropped
# A reloaded page's new websocket can reach the viewer before the old one's close
# does (a busy machine): its claim waits this long for the old page to park.
CLAIM_WAIT_S = 5.0


@dataclass(frozen=True)
class LabMemory:
    """One lab's tabs as the page left them."""

    panels: tuple[PanelMemory, ...]
    private: tuple[str, ...]  # the private messages shown
    watching: str | None  # the context whose world was in the view


class EventKeeper:
    """The lab's events for a parked session, kept in order until a page takes them."""

    def __init__(self, connection: LabConnection, limit: int = MAX_KEPT_EVENTS) -> None:
        self._lock = threading.Lock()
        self._kept: deque[LabEvent] = deque(maxlen=limit)
        self.dropped = 0
        self._to: Callable[[LabEvent], None] | None = None
        self._unsubscribe = connection.subscribe(self._on_event)

    def _on_event(self, event: LabEvent) -> None:
        with self._lock:
            if self._to is None:
                if len(self._kept) == self._kept.maxlen:
                    self.dropped += 1
                self._kept.append(event)
                return
            to = self._to
        to(event)

    def hand_to(self, on_event: Callable[[LabEvent], None]) -> Callable[[], None]:
        """Play the kept events into ``on_event``, then send it every new one; returns: stop.

        Under the lock, so an event arriving meanwhile waits its turn: nothing is
        lost or shown twice, and the order is the lab's.
        """
        with self._lock:
            while self._kept:
                on_event(self._kept.popleft())
            self._to = on_event
        return self._unsubscribe

    def close(self) -> None:
        self._unsubscribe()


@dataclass
class ParkedLab:
    connection: LabConnection
    memory: LabMemory
    events: EventKeeper
    token: bytes
    lab_key: tuple[str, int, str]
    user: str
    until: float  # time.monotonic() past which the session ends

    def page(self) -> HandedOver:
        """What its page had open when it went (for the next viewer)."""
        opened = [(panel.joined.ctx, panel.bench) for panel in self.memory.panels]
        return HandedOver.of(self.user, opened, self.memory.watching)


class ParkingLot:
    """The viewer's parked lab sessions; one thread ends those whose grace has run out."""

    def __init__(self, grace_s: float = DEFAULT_GRACE_S) -> None:
        if grace_s < 0:
            raise ValueError(f"a reload grace of {grace_s} s: must be 0 (off) or more")
        self.grace_s = grace_s
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._parked: list[ParkedLab] = []
        self._attached: dict[bytes, int] = {}  # saved logins that open pages use now
        self._wake = threading.Event()
        self._stopped = False
        self._thread: threading.Thread | None = None

    @property
    def enabled(self) -> bool:
        return self.grace_s > 0

    def grace_words(self) -> str:
        minutes = self.grace_s / 60
        return f"{minutes:g} min" if minutes >= 1 else f"{self.grace_s:g} s"

    def attach(self, connection: LabConnection) -> None:
        """A page uses ``connection`` now (see :meth:`claim`)."""
        token = connection.resume_token
        if token is not None:
            with self._lock:
                self._attached[token] = self._attached.get(token, 0) + 1

    def detach(self, connection: LabConnection) -> None:
        """The page using ``connection`` is gone, and so is the session (not parked)."""
        token = connection.resume_token
        if token is not None:
            with self._changed:
                self._detach(token)
                self._changed.notify_all()

    def _detach(self, token: bytes) -> None:
        left = self._attached.get(token, 0) - 1
        if left > 0:
            self._attached[token] = left
        else:
            self._attached.pop(token, None)

    def park(self, connection: LabConnection, memory: LabMemory, events: EventKeeper) -> bool:
        """Keep ``connection`` for a page to come back to; False: it cannot be (logged out)."""
        token = connection.resume_token
        if not self.enabled or token is None or self._stopped:
            if token is not None:
                self.detach(connection)
            return False
        lab = ParkedLab(
            connection=connection,
            memory=memory,
            events=events,
            token=token,
            lab_key=connection.address.lab_key,
            user=connection.user,
            until=time.monotonic() + self.grace_s,
        )
        with self._changed:
            self._detach(token)
            self._parked.append(lab)
            self._changed.notify_all()
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="parking", daemon=True)
                self._thread.start()
        self._wake.set()
        log.info(
            "%s's page on %s closed: the lab session is kept %s for a reload (%d kept)",
            lab.user,
            connection.address.label,
            self.grace_words(),
            len(self._parked),
        )
        return True

    def claim(
        self, lab_key: tuple[str, int, str], user: str, token: bytes, wait_s: float = CLAIM_WAIT_S
    ) -> ParkedLab | None:
        """The parked session of this saved login, taken out of the lot; None: none.

        While a page still uses that login (a reload whose old page has not closed
        yet), waits up to ``wait_s`` for it to park; a second tab open beside the
        first waits as long, then logs in on its own.
        """
        deadline = time.monotonic() + wait_s
        with self._changed:
            while True:
                lab = self._find(lab_key, user, token)
                if lab is not None:
                    self._parked.remove(lab)
                    break
                left = deadline - time.monotonic()
                if token not in self._attached or left <= 0 or self._stopped:
                    return None
                self._changed.wait(left)
        left = lab.until - time.monotonic()
        log.info(
            "%s is back on %s with %.0f s of grace left: the page takes its session back",
            user,
            lab.connection.address.label,
            left,
        )
        return lab

    def _find(self, lab_key: tuple[str, int, str], user: str, token: bytes) -> ParkedLab | None:
        for lab in self._parked:
            same = lab.lab_key == lab_key and lab.user == user
            if same and hmac.compare_digest(lab.token, token):
                return lab
        return None

    def still_good(self, lab: ParkedLab) -> bool:
        """Whether the registry still honours the parked session; if not, it ends here.

        The lab may have revoked it meanwhile (a password changed, an admin's kick):
        the page must then log in as if nothing had been kept, and be refused in words.
        A registry that cannot say now (restarting, swamped) refuses nothing: the session
        goes back in the lot, its grace running on, and LoginUnavailable is raised.
        """
        try:
            lab.connection.check_resume()
        except LoginUnavailable:
            self._put_back(lab)
            raise
        except LabError as exc:
            self._end(lab, f"the saved login was refused when the page came back ({exc})")
            return False
        return True

    def _put_back(self, lab: ParkedLab) -> None:
        with self._changed:
            if not self._stopped:
                self._parked.append(lab)
                self._changed.notify_all()
                self._wake.set()
                return
        # The viewer stopped meanwhile: as the lot's others were, it is handed over.
        lab.events.close()
        lab.connection.hand_over()

    def __len__(self) -> int:
        with self._lock:
            return len(self._parked)

    def _run(self) -> None:
        while not self._stopped:
            now = time.monotonic()
            with self._lock:
                due = [lab for lab in self._parked if lab.until <= now]
                self._parked = [lab for lab in self._parked if lab.until > now]
                nearest = min((lab.until for lab in self._parked), default=now + 3600.0)
            for lab in due:
                self._end(lab, f"the page was closed for more than {self.grace_words()}")
            self._wake.wait(max(0.05, nearest - time.monotonic()))
            self._wake.clear()

    def _end(self, lab: ParkedLab, reason: str) -> None:
        where = lab.connection.address.label
        log.info("%s on %s: %s; the lab session ends", lab.user, where, reason)
        lab.events.close()
        try:
            lab.connection.logout(keep_resume=True, reason=reason)
        except LabError as exc:
            log.info("logout of %s from %s: %s", lab.user, lab.connection.address.label, exc)
        except Exception:  # one lab's failure must not keep the others' sessions alive
            log.exception("while ending %s's parked session", lab.user)

    def close(self) -> list[tuple[bytes, HandedOver]]:
        """The viewer stops: every parked session is handed over (LabConnection.hand_over),
        as an open page's is: a page that comes back to the next viewer logs in again
        by its saved login. Returns each one's saved login and what its page had open."""
        self._stopped = True
        with self._changed:
            parked, self._parked = self._parked, []
            self._changed.notify_all()
        self._wake.set()
        handed: list[tuple[bytes, HandedOver]] = []
        for lab in parked:
            lab.events.close()
            try:
                lab.connection.hand_over()
            except Exception:  # one lab's failure must not keep the others
                log.exception("while handing over %s's parked session", lab.user)
                continue
            handed.append((lab.token, lab.page()))
        return handed

    def pages(self) -> list[tuple[bytes, HandedOver]]:
        """What each parked session's page had open, by saved login (for the next viewer)."""
        with self._changed:
            parked = list(self._parked)
        return [(lab.token, lab.page()) for lab in parked]
