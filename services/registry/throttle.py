"""The registry's login throttle, and what a login's source is.

A *source* is what the network says, never what the client writes: the Zenoh
session the login query came from (its id, from the query's source info), or,
behind a gateway that vouches for its person (the web viewer, signed with its
own service session), the gateway's account and the address it saw. The
``via`` a client writes in its login is logged beside the source and nothing
more: it may narrow a source in the logs, never make a new one.
"""

from __future__ import annotations

import ipaddress
import math
import threading
from dataclasses import dataclass
from typing import Literal, cast

from common.service import RequestError

Kind = Literal["pair", "source", "network", "account"]
KNOWN_FOR_S = 30 * 86400.0  # a source the account logged in from stays its own this long
MAX_BUCKETS = 100_000  # past this (a flood of names), the oldest half is forgotten


def query_source(zid: str | None) -> str:
    """The source of an unvouched login: the querier's Zenoh session."""
    return f"zenoh:{zid}" if zid else "zenoh:undeclared"


def vouched_source(gateway: str, address: str) -> str:
    """The source of a login a gateway vouches for: its account and the address it saw."""
    return f"{gateway}:{address}"


def network_of(source: str) -> str | None:
    """The network a vouched address is in (IPv4 /24, IPv6 /56); None for a Zenoh session.

    One guesser with many addresses usually has them in one network: this bucket
    counts them together.
    """
    if source.startswith("zenoh:"):
        return None
    gateway, _, address = source.partition(":")
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return None
    bits = 24 if ip.version == 4 else 56
    return f"{gateway}:{ipaddress.ip_network(f'{ip}/{bits}', strict=False)}"


@dataclass(frozen=True)
class Bucket:
    """One throttle as the admin sees it."""

    kind: Kind
    key: str  # "alice|zenoh:ab12", "zenoh:ab12", "viewer:10.0.0.0/24", "alice"
    failures: int
    wait_s: float  # how long a throttled attempt waits now (0: not throttled)


class LoginThrottle:
    """Slows password guessing without letting anyone lock the owner out.

    Four kinds of bucket count failed logins, each allowing a few free failures
    and then an exponential wait (``first_wait``, twice that, four times ... up to
    ``cap`` s after its last failure; 2, 4, 8 ... by default):

    - the *pair* (account, source): one source guessing one account;
    - the *source*, across accounts: one source spraying many accounts;
    - the *network* of a vouched address (:func:`network_of`), across its addresses;
    - the *account*, across every source: many sessions or addresses guessing one
      account get a handful of checks a minute between them, however many they are.

    What keeps an owner in: a source the account logged in from with its password or
    key (its *own* source, for KNOWN_FOR_S: the classroom's address the page vouches
    for) answers to its pair alone, with ``own_free`` free failures (a classmate's
    few guesses leave alice's next login alone) and a short cap (``own_cap``). A
    classmate guessing on from that shared address gets a check every ``own_cap`` s
    at most, and alice, with the right password, waits no longer than that: a
    growing delay, never a lock a third party can hold. Every other source answers
    to all four buckets. Key logins skip the account bucket (a signature cannot be
    guessed). A throttled attempt is refused
    before any password check and is not counted.

    The admin lists every bucket (:meth:`buckets`) and clears an account's
    (:meth:`unlock`: its pair, account, and the sources and networks that failed
    on it) or a source's (:meth:`clear_source`).
    """

    def __init__(
        self,
        free: int = 3,
        source_free: int = 10,
        network_free: int = 30,
        account_free: int = 5,
        own_free: int = 5,
        cap: float = 300.0,
        own_cap: float = 60.0,
        first_wait: float = 2.0,
    ) -> None:
        if not 0 < first_wait <= cap:
            raise ValueError(f"the first wait must be above 0 s and at most {cap:g} s")
        self.first_wait = first_wait
        self.free = {"pair": free, "source": source_free, "network": network_free}
        self.free["account"] = account_free
        self.own_free = own_free
        self.cap = cap
        self.own_cap = max(own_cap, first_wait)
        self._lock = threading.Lock()
        self._fails: dict[tuple[str, str], tuple[int, float]] = {}  # bucket -> (n, last)
        self._own: dict[tuple[str, str], float] = {}  # (account, source) -> last success

    def _wait(
        self, bucket: tuple[str, str], now: float, cap: float, free: int | None = None
    ) -> float:
        count, last = self._fails.get(bucket, (0, 0.0))
        free = self.free[bucket[0]] if free is None else free
        if count < free:
            return 0.0
        return max(0.0, last + min(cap, self.first_wait * 2.0 ** (count - free)) - now)

    @staticmethod
    def _buckets(user: str, source: str) -> list[tuple[str, str]]:
        found = [("pair", f"{user}|{source}"), ("source", source), ("account", user)]
        network = network_of(source)
        if network is not None:
            found.append(("network", network))
        return found

    def is_own(self, user: str, source: str, now: float) -> bool:
        with self._lock:
            at = self._own.get((user, source))
        return at is not None and now - at < KNOWN_FOR_S

    def check(self, user: str, source: str, now: float, *, key_login: bool = False) -> None:
        own = self.is_own(user, source, now)
        with self._lock:
            if own:
                wait = self._wait(("pair", f"{user}|{source}"), now, self.own_cap, self.own_free)
            else:
                wait = max(
                    self._wait(b, now, self.cap)
                    for b in self._buckets(user, source)
                    if not (key_login and b[0] == "account")
                )
        if wait > 0:
            raise RequestError(
                "rate_limited",
                f"too many failed logins from here: try again in {math.ceil(wait)} s",
                retry_after=wait,
            )

    def failed(self, user: str, source: str, now: float) -> None:
        with self._lock:
            for bucket in self._buckets(user, source):
                count, _ = self._fails.get(bucket, (0, 0.0))
                self._fails[bucket] = (count + 1, now)
            if len(self._fails) > MAX_BUCKETS:
                for bucket in sorted(self._fails, key=lambda b: self._fails[b][1])[
                    : MAX_BUCKETS // 2
                ]:
                    del self._fails[bucket]

    def succeeded(self, user: str, source: str, now: float, *, own: bool = True) -> None:
        """The right credential from this source: its pair is clean, and (``own``: a
        password or key, not a saved login that may be a copy) it is the account's."""
        with self._lock:
            self._fails.pop(("pair", f"{user}|{source}"), None)
            if not own:
                return
            if len(self._own) > MAX_BUCKETS:
                self._own = {k: t for k, t in self._own.items() if now - t < KNOWN_FOR_S}
            self._own[(user, source)] = now

    def failures(self, user: str) -> int:
        """Failed logins on the account since its last unlock (for the admin's list)."""
        with self._lock:
            return self._fails.get(("account", user), (0, 0.0))[0]

    def buckets(self, now: float) -> list[Bucket]:
        """Every bucket with a failure, most failures first."""
        with self._lock:
            found = [
                Bucket(cast(Kind, kind), key, count, self._wait((kind, key), now, self.cap))
                for (kind, key), (count, _) in self._fails.items()
            ]
        return sorted(found, key=lambda b: (-b.failures, b.kind, b.key))

    def unlock(self, user: str) -> int:
        """Forget the failures on the account (admin), and of the sources that made them.

        A shared address (a classroom's) whose guesses at alice also slowed its other
        logins is clear again too. How many buckets were cleared.
        """
        with self._lock:
            pairs = [b for b in self._fails if b[0] == "pair" and b[1].startswith(f"{user}|")]
            sources = {b[1].partition("|")[2] for b in pairs}
            gone = [*pairs, ("account", user)]
            for source in sources:
                gone.append(("source", source))
                network = network_of(source)
                if network is not None:
                    gone.append(("network", network))
            return sum(self._fails.pop(b, None) is not None for b in gone)

    def clear_source(self, source: str) -> int:
        """Forget every failure from this source or network (admin): how many buckets."""
        with self._lock:
            gone = [
                b
                for b in self._fails
                if b[1] == source or (b[0] == "pair" and b[1].endswith(f"|{source}"))
            ]
            for bucket in gone:
                del self._fails[bucket]
            return len(gone)
