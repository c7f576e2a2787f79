"""The base every long-running process builds on.

A service's logic is a plain class that takes an open Zenoh session, so tests
can drive it in-process. :func:`run_service` is the thin part every ``main()``
shares: open the session (waiting for the router, and saying so), start the
service, stop on SIGINT/SIGTERM, close the session with a deadline so the
process never hangs at exit.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, ClassVar, NoReturn, TypeVar

import zenoh

from common import keys
from common.auth import AuthError
from common.keys import AliveKind
from common.messages import ErrorCode, ErrorReply, Message, MessageError, encode
from common.zconfig import NetworkOptions, zenoh_config

log = logging.getLogger("wart.service")

S = TypeVar("S", bound="Service")


class Service:
    """A process's logic on the Zenoh network, with a liveliness token.

    Subclasses set ``kind``, declare what they serve in :meth:`on_start`
    through :meth:`subscribe` / :meth:`serve` (so :meth:`stop` can undeclare
    them), and release their own resources in :meth:`on_stop`.
    """

    kind: ClassVar[AliveKind]

    def __init__(self, session: zenoh.Session, realm: str, ident: str) -> None:
        keys.check_ident(self.kind.value, ident)
        self.session = session
        self.realm = realm
        self.ident = ident
        self.log = logging.getLogger(f"wart.{self.kind.value}.{ident}")
        self._declared: list[Any] = []
        self._pools: list[ThreadPoolExecutor] = []
        self._token: Any = None
        self._started = False
        self._stopped = threading.Event()
        self.dropped = 0  # puts refused (malformed, unauthenticated, forbidden)

    @property
    def alive_key(self) -> str:
        return keys.alive(self.realm, self.kind, self.ident)

    # -- lifecycle

    def start(self: S) -> S:
        if self._started:
            return self
        self.on_start()
        # The token goes last: once others see it, everything is being served.
        self._token = self.session.liveliness().declare_token(self.alive_key)
        self._started = True
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop serving and undeclare everything; safe to call twice."""
        if self._stopped.is_set():
            return
        self._stopped.set()
        deadline = time.monotonic() + timeout
        if self._token is not None:
            _quietly(self._token.undeclare)
            self._token = None
        try:
            self.on_stop(max(0.1, deadline - time.monotonic()))
        except Exception:
            self.log.exception("error while stopping")
        for handle in reversed(self._declared):
            _quietly(handle.undeclare)
        self._declared.clear()
        for pool in self._pools:  # queries being answered finish; waiting ones are dropped
            pool.shutdown(wait=False, cancel_futures=True)

    @property
    def stopped(self) -> bool:
        return self._stopped.is_set()

    def __enter__(self: S) -> S:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def on_start(self) -> None:
        """Declare subscribers and queryables here."""

    def on_stop(self, timeout: float) -> None:
        """Release the service's own resources (threads, files) within ``timeout``."""

    # -- declarations

    def track(self, handle: Any) -> Any:
        """Remember a Zenoh declaration so stop() undeclares it."""
        self._declared.append(handle)
        return handle

    def subscribe(self, key_expr: str, handler: Callable[[zenoh.Sample], None]) -> Any:
        """A callback subscriber whose exceptions are logged and counted, never fatal."""

        def guarded(sample: zenoh.Sample) -> None:
            try:
                handler(sample)
            except (AuthError, MessageError) as exc:
                self.dropped += 1
                self.log.warning("dropped a message on %s: %s", sample.key_expr, str(exc))
            except Exception:
                self.dropped += 1
                self.log.error(
                    "error handling a message on %s (kept serving):\n%s",
                    sample.key_expr,
                    traceback.format_exc(),
                )

        return self.track(self.session.declare_subscriber(key_expr, guarded))

    def serve(
        self,
        key_expr: str,
        handler: Callable[[zenoh.Query], Message],
        *,
        workers: int = 0,
        max_waiting: int = 256,
        stale_after: float = 0.0,
    ) -> Any:
        """A queryable: ``handler`` returns the reply message; errors become ErrorReply.

        Zenoh calls one queryable's callback one query at a time. A handler that
        spends real CPU outside the GIL (argon2id password checks) gets
        ``workers`` threads instead, so queries are answered in parallel on every
        core; at most ``max_waiting`` queries wait for a worker, and the next is
        told the service is busy rather than queued without bound. A query that has
        waited more than ``stale_after`` seconds (its querier has given up by then) is
        told the service is busy without running the handler: under a burst the
        workers spend their time on logins somebody still waits for.
        """

        def guarded(query: zenoh.Query) -> None:
            reply: Message
            try:
                reply = handler(query)
            except AuthError as exc:
                self.log.info("refused a request on %s: %s", query.key_expr, exc.message)
                reply = ErrorReply(code=exc.code, message=exc.message)
            except MessageError as exc:
                # Words, never the exception: the log keeps its last record, and the
                # exception's frames hold the query, whose end would wait for the GC.
                self.log.info("bad request on %s: %s", query.key_expr, str(exc))
                reply = ErrorReply(code="bad_request", message=str(exc))
            except RequestError as exc:
                reply = ErrorReply(code=exc.code, message=exc.message, retry_after=exc.retry_after)
            except Exception:
                self.log.error(
                    "error serving %s (kept serving):\n%s", query.key_expr, traceback.format_exc()
                )
                reply = ErrorReply(code="internal", message="internal error; see the service log")
            try:
                query.reply(query.key_expr, encode(reply))
            except Exception as exc:  # the querier may have gone away
                self.log.debug("could not reply on %s: %s", query.key_expr, exc)

        if workers <= 0:
            return self.track(self.session.declare_queryable(key_expr, guarded))

        pool = ThreadPoolExecutor(workers, thread_name_prefix=f"{self.ident}-serve")
        slots = threading.BoundedSemaphore(workers + max_waiting)
        self._pools.append(pool)

        def in_pool(query: zenoh.Query, queued_at: float) -> None:
            try:
                waited = time.monotonic() - queued_at
                if stale_after > 0 and waited > stale_after:
                    self.log.warning(
                        "a query on %s waited %.1f s for a worker, longer than its asker "
                        "waits: skipped it",
                        key_expr,
                        waited,
                    )
                    _reply_busy(query)
                else:
                    guarded(query)
            finally:
                query.drop()  # the reply leaves now, not when the object is collected
                slots.release()

        def dispatch(query: zenoh.Query) -> None:
            if not slots.acquire(blocking=False):
                self.log.warning("too many queries waiting on %s: told the querier", key_expr)
                _reply_busy(query)
                return
            try:
                pool.submit(in_pool, query, time.monotonic())
            except RuntimeError:  # stopping: the pool takes no more work
                slots.release()

        return self.track(self.session.declare_queryable(key_expr, dispatch))


def _reply_busy(query: zenoh.Query) -> None:
    reply = ErrorReply(
        code="rate_limited", message="the service is busy: try again", retry_after=0.5
    )
    try:
        query.reply(query.key_expr, encode(reply))
    except Exception as exc:  # the querier may have gone away
        log.debug("could not reply on %s: %s", query.key_expr, exc)


class RequestError(Exception):
    """Raised by a handler to answer a request with an ErrorReply."""

    def __init__(self, code: ErrorCode, message: str, retry_after: float = 0.0) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.retry_after = retry_after


def _quietly(fn: Callable[[], object]) -> None:
    try:
        fn()
    except Exception as exc:
        log.debug("ignored while stopping: %s", exc)


# --- running a service as a process -------------------------------------------------


def zenoh_reason(exc: Exception | None) -> str:
    """Zenoh's error text without the Rust source location it appends."""
    if exc is None:
        return ""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return re.sub(r"\s+at /\S+\.rs:\d+\.?$", "", text).rstrip()


def open_session(
    options: NetworkOptions,
    *,
    wait: float | None = None,
    quiet: bool = False,
    stop: threading.Event | None = None,
) -> zenoh.Session:
    """Open a Zenoh session, retrying while no router answers.

    ``wait`` is how long to keep trying (None: until ``stop`` is set);
    ``quiet`` skips the "waiting for a router" warning (a router just started).
    Raises ConnectionError when ``wait`` runs out or ``stop`` is set.
    """
    conf_error: Exception | None = None
    delay = 0.2
    deadline = None if wait is None else time.monotonic() + wait
    announced = False
    while True:
        try:
            return zenoh.open(zenoh_config(options))
        except Exception as exc:  # zenoh raises ZError for an unreachable router
            conf_error = exc
        if deadline is not None and time.monotonic() >= deadline:
            raise ConnectionError(
                f"no Zenoh router reachable at {', '.join(options.effective_connect)}: "
                f"{zenoh_reason(conf_error)}"
            )
        if not announced and not quiet:
            log.warning(
                "waiting for a Zenoh router at %s (%s)",
                ", ".join(options.effective_connect) or "(scouting)",
                zenoh_reason(conf_error),
            )
            announced = True
        if stop is not None and stop.wait(delay):
            raise ConnectionError("stopped while waiting for a Zenoh router")
        if stop is None:
            time.sleep(delay)
        delay = min(delay * 2, 2.0)


def has_subscribers(publisher: zenoh.Publisher) -> bool:
    """Whether any subscriber matches ``publisher`` now.

    zenoh's stub types ``matching_status`` as a bool; it is a MatchingStatus,
    whose ``matching`` is the bool.
    """
    status: Any = publisher.matching_status
    return bool(status.matching)


# Closes that outlived close_session's wait, their threads still inside Zenoh.
_late_closes: list[threading.Thread] = []


def close_session(session: zenoh.Session, timeout: float = 5.0) -> bool:
    """Close a session within ``timeout``; False if Zenoh did not finish in time (the
    process must then end by :func:`exit_process`)."""
    done = threading.Event()

    def closer() -> None:
        _quietly(session.close)
        done.set()

    thread = threading.Thread(target=closer, name="zenoh-close", daemon=True)
    thread.start()
    if done.wait(timeout):
        return True
    _late_closes.append(thread)
    return False


def exit_process(code: int) -> NoReturn:
    """End this process with ``code``, also while a session is still closing.

    A thread that comes back from Zenoh's Rust code after the interpreter began
    to shut down aborts the process ("FATAL: exception not rethrown", exit 134):
    a command whose session took longer to close than close_session waited (a
    busy machine) printed its result and then failed. Such a process ends here
    without the interpreter's shutdown, its output flushed.
    """
    if any(thread.is_alive() for thread in _late_closes):
        logging.shutdown()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)
    sys.exit(code)


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT (Ctrl-C) or SIGTERM: a process's cue to stop cleanly."""
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return stop


def run_service(
    name: str,
    options: NetworkOptions,
    build: Callable[[zenoh.Session], Service],
    *,
    wait_for_router: float | None = None,
    stop_timeout: float = 5.0,
) -> int:
    """Run a service until SIGINT or SIGTERM; the body of every service ``main()``.

    Returns the process exit code. If Zenoh does not close in time the process
    exits anyway (``os._exit``) rather than hang.
    """
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        log.info("%s: received %s, stopping", name, signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)

    try:
        # with stop: SIGTERM while no router answers ends the wait (it looped on)
        session = open_session(options, wait=wait_for_router, stop=stop)
    except ConnectionError as exc:
        if stop.is_set():
            log.info("%s stopped before a router answered", name)
            return 0
        log.error("%s: %s", name, exc)
        return 2
    service: Service | None = None
    code = 0
    try:
        service = build(session)
        service.start()
        log.info("%s is up (realm %s, token %s)", name, options.realm, service.alive_key)
        while not stop.wait(0.5):
            if service.stopped:
                break
    except Exception:
        log.error("%s failed:\n%s", name, traceback.format_exc())
        code = 1
    finally:
        if service is not None:
            service.stop(stop_timeout)
        if not close_session(session, stop_timeout):
            log.error("%s: Zenoh did not close within %.0f s; exiting anyway", name, stop_timeout)
            logging.shutdown()
            os._exit(code or 1)
    log.info("%s stopped", name)
    return code
