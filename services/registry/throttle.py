"""The registry's login throttle, and what a login's source is.

A *source* is what the network says, never what the client writes: the Zenoh
session the login query came from (its id, from the query's source info), or,
behind a gateway that vouches for its person (the web viewer, signed with its
own service session), the gateway's account and the address it saw. The
``via`` a client writes in its login is logged beside the source and nothing
more: it may narrow a source in the logs, never make a new one.
"""

from __future__ import annotations

import math
import threading

from common.service import RequestError


def query_source(zid: str | None) -> str:
    """The source of an unvouched login: the querier's Zenoh session."""
    return f"zenoh:{zid}" if zid else "zenoh:undeclared"


def vouched_source(gateway: str, address: str) -> str:
    """The source of a login a gateway vouches for: its account and the address it saw."""
    return f"{gateway}:{address}"


class LoginThrottle:
    """Slows password guessing without letting anyone lock the owner out.

    Three buckets of failed logins, each allowed a few free failures and then an
    exponential wait (``first_wait``, twice that, four times ... up to ``cap``
    seconds after the last failure; 2, 4, 8 ... by default):

    - the *pair* (account, source): one source guessing one account;
    - the *source*, across accounts: one source spraying many accounts;
    - the *account*, across sources: distributed guessing. This one applies only
      to sources that already failed on the account ("suspect" sources). A
      source with no failure on the account is still checked, so the owner's
      correct password gets through while others guess; a wrong one makes that
      source suspect, and every later try from it waits the account's time too.

    Key logins are exempt from the account bucket (a signature cannot be
    guessed). The admin's unlock clears every bucket of an account.

    The source is :func:`query_source` or :func:`vouched_source` (module
    docstring). A client that opens a fresh Zenoh session for every attempt is a
    new source each time, slowed only by the session's setup, the argon2id cost
    of each check and the router's access control (docs/SECURITY.md says so).
    """

    def __init__(
        self,
        free: int = 3,
        source_free: int = 10,
        account_free: int = 10,
        cap: float = 300.0,
        first_wait: float = 2.0,
    ) -> None:
        if not 0 < first_wait <= cap:
            raise ValueError(f"the first wait must be above 0 s and at most {cap:g} s")
        self.first_wait = first_wait
        self.free = free
        self.source_free = source_free
        self.account_free = account_free
        self.cap = cap
        self._lock = threading.Lock()
        self._fails: dict[str, tuple[int, float]] = {}  # bucket -> (failures, last failure)

    def _wait(self, bucket: str, free: int, now: float) -> float:
        count, last = self._fails.get(bucket, (0, 0.0))
        if count < free:
            return 0.0
        return max(0.0, last + min(self.cap, self.first_wait * 2.0 ** (count - free)) - now)

    @staticmethod
    def _buckets(user: str, source: str) -> tuple[str, str, str]:
        return f"pair:{user}|{source}", f"source:{source}", f"user:{user}"

    def check(self, user: str, source: str, now: float, *, key_login: bool = False) -> None:
        pair, by_source, account = self._buckets(user, source)
        with self._lock:
            wait = max(
                self._wait(pair, self.free, now), self._wait(by_source, self.source_free, now)
            )
            suspect = pair in self._fails
            if suspect and not key_login:
                wait = max(wait, self._wait(account, self.account_free, now))
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
            if len(self._fails) > 100_000:  # a flood of names: forget the oldest half
                for bucket in sorted(self._fails, key=lambda b: self._fails[b][1])[:50_000]:
                    del self._fails[bucket]

    def succeeded(self, user: str, source: str) -> None:
        """The right credential from this source: its pair is clean again."""
        with self._lock:
            self._fails.pop(self._buckets(user, source)[0], None)

    def failures(self, user: str) -> int:
        """Failed logins on the account since its last unlock (for the admin's list)."""
        with self._lock:
            return self._fails.get(f"user:{user}", (0, 0.0))[0]

    def unlock(self, user: str) -> int:
        """Forget every failure on the account (admin): how many buckets were cleared."""
        with self._lock:
            gone = [b for b in self._fails if b == f"user:{user}" or b.startswith(f"pair:{user}|")]
            for bucket in gone:
                del self._fails[bucket]
            return len(gone)
