"""The login form: a modal in one browser only (viser GUI is per client).

viser has no login hook and no password input: the password field is made a
real ``<input type="password">`` in the page (viewers/web/masked.py), Enter
in either field presses "Log in", the field is cleared as soon as the
attempt is made, and a deployment that leaves the lab network should sit
behind an HTTPS reverse proxy (docs/OPERATIONS.md).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import viser

from common.auth import LOGIN_WAIT_S
from common.client.lab_address import LabAddress
from common.keys import is_ident
from viewers.web.adapters import LabConnection, LabConnector, LabError
from viewers.web.inputs import on_click, set_value
from viewers.web.masked import add_masked_text, add_submit_on_enter
from viewers.web.viser_fast import browser_address

log = logging.getLogger("wart.viewer.login")

MAX_PASSWORD = 1024

LOGIN_WORKERS = 4
"""Logins one viewer runs at once. Each holds a thread while its mailbox key is derived
(argon2id, ~100 ms of a core and 64 MiB) and while the registry checks the password on
its one worker per core: more at once only queue at the registry instead of here."""

QUEUE_WAIT_S = LOGIN_WAIT_S
"""How long a click waits for a free login worker before the page says the lab is busy.
With the registry's own LOGIN_WAIT_S, a student hears back within about twice that."""

BUSY = (
    "Could not log in: the lab is busy, many people are logging in at once. Try again in a minute."
)
BROKEN = (
    "Could not log in: something went wrong in this web viewer. Try again; if it "
    "happens again, tell the lab's staff."
)
STOPPING = "Could not log in: this web viewer is stopping. Reload the page in a minute."

PROGRESS_AFTER_S = 1.0
"""A login still under way after this long says how long it has waited, every half second:
when a class logs in at once each password check queues (argon2id, ~75 ms of a core)."""


def progress_words(waited: float, queued_here: int) -> str:
    """What the form says while a login takes long (a second and more)."""
    words = f"Logging in... {waited:.0f} s"
    if queued_here > 0:
        return f"{words}: {queued_here} more logins wait here; many people are logging in at once."
    return f"{words}: the lab is checking the password (each check takes time on purpose)."


@dataclass
class _Job:
    run: Callable[[], None]
    too_late: Callable[[], None]
    queued: float


class LoginDesk:
    """The viewer's own login threads, so a login never holds one of viser's.

    viser runs every callback of every browser (clicks, typing, a new page's set-up) on
    one pool of 32 threads. A login blocks for the mailbox key's argon2id and then for
    the registry (up to LOGIN_WAIT_S), so a class logging in at once took that whole
    pool, and every page of the viewer stopped answering clicks, logged-in students'
    too, for as long as the logins queued. Here a click only queues the login; at most
    ``workers`` run, and a login that waited ``queue_wait`` seconds for one is answered
    "busy, try again" by the watch thread, whether or not a worker is free by then: the
    student always hears back within ``queue_wait`` plus one login.
    """

    def __init__(self, workers: int = LOGIN_WORKERS, queue_wait: float = QUEUE_WAIT_S) -> None:
        if workers < 1 or queue_wait <= 0:
            raise ValueError("a login desk needs a worker and a positive wait")
        self.queue_wait = queue_wait
        self._jobs: deque[_Job] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._threads = [
            threading.Thread(target=self._work, name=f"login-{i}", daemon=True)
            for i in range(workers)
        ]
        self._threads.append(threading.Thread(target=self._watch, name="login-watch", daemon=True))
        for thread in self._threads:
            thread.start()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def waiting(self) -> int:
        with self._cond:
            return len(self._jobs)

    def submit(self, run: Callable[[], None], too_late: Callable[[], None]) -> None:
        """Queue ``run``; ``too_late`` is called instead if it waits too long (or we stop)."""
        with self._cond:
            if not self._closed:
                self._jobs.append(_Job(run, too_late, time.monotonic()))
                self._cond.notify_all()  # a worker, and the watch thread's next deadline
                return
        _call(too_late)

    def close(self) -> None:
        """Stop taking logins; the ones still waiting are told the viewer is stopping."""
        with self._cond:
            self._closed = True
            left = list(self._jobs)
            self._jobs.clear()
            self._cond.notify_all()
        for job in left:
            _call(job.too_late)

    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._jobs and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job = self._jobs.popleft()
            late = time.monotonic() - job.queued > self.queue_wait
            _call(job.too_late if late else job.run)

    def _watch(self) -> None:
        while True:
            with self._cond:
                if self._closed:
                    return
                now = time.monotonic()
                late = []
                while self._jobs and now - self._jobs[0].queued > self.queue_wait:
                    late.append(self._jobs.popleft())
                if not late:
                    oldest = self._jobs[0].queued if self._jobs else now
                    self._cond.wait(max(0.05, oldest + self.queue_wait - now))
                    continue
            for job in late:
                log.warning(
                    "a login waited %.0f s for a worker: told the student to retry", self.queue_wait
                )
                _call(job.too_late)


def _call(fn: Callable[[], None]) -> None:
    try:
        fn()
    except Exception:  # one page's broken callback must not stop the desk
        log.exception("in a login callback")


def check_login_input(user: str, password: str) -> str | None:
    """What is wrong with the typed user/password, in plain words (None: nothing)."""
    if not user:
        return "Type your user name."
    if not is_ident(user):
        return "A user name has only letters, digits, '_', '-' or '.'."
    if not password:
        return "Type your password."
    if len(password) > MAX_PASSWORD:
        return "That password is too long."
    return None


class LoginForm:
    """Asks for a user and password, calls the connector, reports plain-words errors."""

    def __init__(
        self,
        client: viser.ClientHandle,
        connector: LabConnector,
        address: LabAddress,
        on_success: Callable[[LabConnection], None],
        desk: LoginDesk,
    ) -> None:
        self.client = client
        self.connector = connector
        self.desk = desk
        self._busy = threading.Lock()  # held from the click until the answer is shown
        self.address = address
        self.on_success = on_success
        self.closed = False
        self._done = threading.Event()  # set when the login under way is answered
        # The progress thread and the answer both write the form's message: under one
        # lock, so "Logging in... 5 s" can never land after the answer and hide it for
        # good (seen under load: three wrong passwords left on "Logging in...").
        self._message = threading.Lock()
        # Held back until the handlers below are registered: viser sends each button
        # as it is made, and a click that reaches the viewer before its handler is
        # dropped without a trace. On a loaded viewer the thread building the form can
        # wait for the GIL long enough for a quick browser to click "Log in" in between
        # (seen: 1 to 2 of 100 headless logins at load 11 to 17); that student's form
        # then stayed on screen with no answer, for good.
        with client.atomic():
            self.modal = client.gui.add_modal(f"Log in to {address.label}")
            with self.modal:
                client.gui.add_markdown(f"Lab at `{address.url(with_user=False)}`")
                self.user = client.gui.add_text("User", address.user or "")
                add_submit_on_enter(client.gui, self.user, "Log in")  # Enter logs in
                self.password = add_masked_text(client.gui, "Password", submit="Log in")
                self.error = client.gui.add_markdown("", visible=False)
                self.submit = client.gui.add_button("Log in", color="green")
                self.cancel = client.gui.add_button("Cancel")
            on_click(self.submit, self.attempt)
            self.cancel.on_click(lambda _: self.close())

    def show_error(self, text: str) -> None:
        self.error.content = f"**{text}**"
        self.error.visible = True

    def attempt(self) -> bool:
        """The "Log in" click (on viser's thread): check what was typed, queue the login.

        False if nothing was queued (a problem with the input, shown, or a login of
        this form already on its way: a second click waits for the first's answer).
        """
        user = self.user.value.strip()
        password = self.password.value
        set_value(self.password, "")  # never leave it on screen or in the GUI state
        problem = check_login_input(user, password)
        if problem:
            self.show_error(problem)
            return False
        if not self._busy.acquire(blocking=False):
            return False
        self.submit.disabled = True
        self.error.content = "Logging in..."
        self.error.visible = True
        clicked = time.monotonic()
        self._done = threading.Event()
        threading.Thread(
            target=self._progress, args=(clicked, self._done), name="login-progress", daemon=True
        ).start()

        def too_late() -> None:
            self._answered(STOPPING if self.desk.closed else BUSY, clicked)

        self.desk.submit(lambda: self._log_in(user, password, clicked), too_late)
        return True

    def _progress(self, clicked: float, done: threading.Event) -> None:
        """Past PROGRESS_AFTER_S, the form says how long the login has waited, until answered."""
        while not done.wait(0.5):
            with self._message:
                waited = time.monotonic() - clicked
                if waited >= PROGRESS_AFTER_S and not self.closed and not done.is_set():
                    self.error.content = progress_words(waited, self.desk.waiting)

    def _log_in(self, user: str, password: str, clicked: float) -> None:
        """On a login thread: ask the lab, then show the answer (or the lab's tab)."""
        try:
            connection = self.connector.login(
                self.address.with_user(user),
                user,
                password,
                via=f"browser-{self.client.client_id}",
                seen_from=browser_address(self.client),
            )
        except LabError as exc:
            self._answered(f"Could not log in: {exc}", clicked)
            return
        except (OSError, TimeoutError) as exc:
            log.info("login to %s failed: %s", self.address.label, exc)
            self._answered(
                f"Could not reach the lab at {self.address.label}: check the address, "
                "or try again in a minute.",
                clicked,
            )
            return
        except Exception:
            log.exception("login of %s to %s", user, self.address.label)
            self._answered(BROKEN, clicked)
            return
        with self._message:
            self._done.set()
        log.info(
            "browser %d: %s logged in to %s after %.1f s",
            self.client.client_id,
            user,
            self.address.label,
            time.monotonic() - clicked,
        )
        try:
            self.close()
        finally:
            self._busy.release()
        try:
            self.on_success(connection)
        except Exception:
            # In, but the lab's tab could not be built: say so rather than show nothing.
            log.exception("opening %s's tab for %s", self.address.label, user)
            self.client.add_notification(
                title=f"Logged in, but {self.address.label}'s tab could not open",
                body="Reload the page and log in again; if it happens again, tell the staff.",
                color="red",
            )

    def _answered(self, text: str, clicked: float) -> None:
        with self._message:
            self._done.set()
        log.info(
            "browser %d: login to %s ended after %.1f s: %s",
            self.client.client_id,
            self.address.label,
            time.monotonic() - clicked,
            text,
        )
        try:
            self.show_error(text)
            self.submit.disabled = False
        finally:
            self._busy.release()  # whatever happened to the page, the next click is heard

    def close(self) -> None:
        self.closed = True
        self.modal.close()
