"""``wart lti``: an LTI 1.3 tool, so a course in Moodle, Canvas or any LMS launches into the lab.

A student or teacher clicks the lab's link in their LMS course. The LMS and the
browser do LTI 1.3's OIDC login and launch against this service's HTTP
endpoint (services/lti/web.py); the launch is verified (services/lti/launch.py)
and mapped: the platform's user (issuer + sub) to a lab account, made on the
first launch and matched after (the registry makes it: ``registry/lti``, which
only this service's account, role ``lti``, may ask); the LMS's roles to a
course role (Instructor, TeachingAssistant -> teacher; Learner -> student); its
course (context) to a lab course (the platforms file, or the context's label);
its resource link to an assignment (the file, or the custom parameter
``assignment=NAME``). The browser then lands on the lab's page logged in: the
registry's resume token for that account, used once, in the page's saved-login
cookie (common/client/resume_cookie.py).

When the grader announces a graded submission (``grader/<g>/graded``) of a
student who launched that assignment from an LMS offering grade passback, its
score goes to the launch's line item (services/lti/ags.py), through an outbox
that outlives an LMS outage and this service's restarts. Token:
``alive/lti/<name>``.
"""

from __future__ import annotations

import logging
import threading

import zenoh

from common import keys
from common.auth import AuthError, Verifier
from common.client.grader_client import GraderClient
from common.client.lab_address import AddressError, parse_address
from common.client.resume_cookie import cookie_name, cookie_value
from common.client.service_login import ServiceLogin
from common.keys import AliveKind, is_ident
from common.lab_errors import LabError, RegistryUnreachable
from common.messages import Graded, LtiAccount, LtiAccountRequest
from common.service import Service
from services.lti.ags import Passback
from services.lti.config import LtiConfig
from services.lti.launch import Launch, Launcher, LaunchError
from services.lti.store import LaunchLink, LtiStore, Outgoing
from services.lti.tool_key import ToolKey
from services.lti.web import Landing, ToolServer

log = logging.getLogger("wart.lti")

LAUNCH_COOKIE_S = 600  # the resume token in it is good for as long (lti_links.py)
CATCH_UP_FIRST_S = 2.0  # after the start: the grader may be starting too
CATCH_UP_S = 300.0


class LtiService(Service):
    kind = AliveKind.LTI

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        name: str,
        *,
        config: LtiConfig,
        login: ServiceLogin,
        registry_key: bytes,
        store: LtiStore,
        key: ToolKey,
        http_host: str = "127.0.0.1",
        http_port: int = 8090,
    ) -> None:
        super().__init__(session, realm, name)
        self.config = config
        self.login = login
        self.verifier = Verifier(registry_key, realm)
        self.store = store
        self.key = key
        self.launcher = Launcher(config)
        self.passback = Passback(config, store, key)
        self.http = ToolServer(http_host, http_port, self.launcher, self.on_launch, key.jwks())
        self._stop = threading.Event()
        self._graded = threading.Event()  # a submission was announced graded: ask now
        self._catch_up_wait = CATCH_UP_FIRST_S
        self._catch_up = threading.Thread(target=self._catch_up_loop, name="catch-up", daemon=True)
        try:
            self.address = parse_address(config.lab_address, default_realm=realm)
        except AddressError as exc:
            raise ValueError(f"tool.lab_address: {exc}") from None

    def on_start(self) -> None:
        self.subscribe(keys.grader_graded(self.realm, self.config.grader), self.on_graded)
        self.passback.start()
        self.http.start()
        self._catch_up.start()
        self.log.info("LTI tool on %s (login %s)", self.config.url, self.config.login_url)

    def on_stop(self, timeout: float) -> None:
        self._stop.set()
        self._graded.set()
        self.http.stop(timeout / 3)
        self.passback.stop(timeout / 3)
        self._catch_up.join(timeout / 3)

    # -- a launch

    def _course(self, launch: Launch) -> str:
        p = launch.platform
        for known in (launch.context_id, launch.context_label):
            if known and known in p.courses:
                return p.courses[known]
        if is_ident(launch.context_label):
            return launch.context_label
        raise LaunchError(
            403,
            f"the LMS course {launch.context_label or launch.context_id!r} is not mapped to a "
            "course of the lab: add it to [platform.courses] in the lti config",
        )

    def _assignment(self, launch: Launch) -> str | None:
        named = launch.platform.assignments.get(launch.resource_link)
        named = named or launch.custom.get("assignment") or None
        if named is not None and not is_ident(named):
            raise LaunchError(400, f"the link's assignment {named!r} is not a lab name")
        return named

    def on_launch(self, launch: Launch) -> Landing:
        role = launch.role
        if role is None:
            raise LaunchError(
                403,
                "your role in the LMS course ("
                + (", ".join(r.rpartition("#")[2] for r in launch.roles) or "none")
                + ") is neither a teacher's nor a learner's: the lab has no place for it",
            )
        course = self._course(launch)
        assignment = self._assignment(launch)
        request = LtiAccountRequest(
            issuer=launch.platform.issuer,
            subject=launch.subject,
            course=course,
            role=role,  # type: ignore[arg-type]
            name=launch.name,
            email=launch.email,
        )
        try:
            account = self.login.client._ask(
                keys.registry_lti(self.realm), request, LtiAccount, "an LTI launch's account",
                timeout=10.0,
            )  # fmt: skip
        except RegistryUnreachable as exc:
            raise LaunchError(503, f"the lab's registry did not answer ({exc})") from None
        except LabError as exc:
            raise LaunchError(403, f"the lab refused the launch: {exc}") from None
        if assignment is not None and launch.lineitem is not None and role == "student":
            link = LaunchLink(
                launch.platform.issuer, launch.platform.client_id, launch.subject, launch.lineitem
            )
            self.store.record_launch(account.user, assignment, link)
        how = "new account" if account.created else "account"
        self.log.info(
            "launch from %s: %s %s as %s in %s%s",
            launch.platform.issuer, how, account.user, role, course,
            f", assignment {assignment}" if assignment else "",
        )  # fmt: skip
        address = self.address.with_user(account.user)
        cookie = (
            f"{cookie_name(address)}={cookie_value(address, account.resume)}; Path=/; "
            f"Max-Age={LAUNCH_COOKIE_S}; SameSite=Lax; HttpOnly"
            + ("; Secure" if self.config.page.startswith("https://") else "")
        )
        return Landing(self.config.page, [cookie])

    # -- grade passback

    def on_graded(self, sample: zenoh.Sample) -> None:
        """A submission is graded: the announcement names no one and no score (anyone may
        read it), so the catch-up asks the grader now, off this Zenoh callback."""
        principal, graded = self.verifier.open(str(sample.key_expr), sample.payload, Graded)
        if "service" not in principal.roles:
            raise AuthError("forbidden", f"{principal.user} is not a service: no grades from it")
        self.log.debug("%s graded: asking the grader for its score", graded.submission)
        self._graded.set()

    def _pass_back(
        self, submission: str, user: str, assignment: str, score: float, graded_at: float
    ) -> bool:
        """Keep a graded submission's score for the platform; True if newly kept."""
        link = self.store.launch_of(user, assignment)
        if link is None:
            return False  # not launched from an LMS with grade passback: nothing to pass back
        platform = self.config.platform(link.issuer, link.client_id)
        if platform is None:
            self.log.warning("%s's score has no platform any more (%s)", user, link.issuer)
            return False
        out = Outgoing(
            submission=submission,
            user=user,
            assignment=assignment,
            issuer=link.issuer,
            client_id=link.client_id,
            subject=link.subject,
            lineitem=link.lineitem,
            score=score,
            maximum=platform.score_maximum,
            graded_at=graded_at,
            attempts=0,
        )
        if not self.store.enqueue(out):
            self.log.info("score of %s was already passed on: not posted twice", submission)
            return False
        self.log.info("score of %s for %s (%s): %g, to be posted to %s",
                      submission, user, assignment, score, link.issuer)  # fmt: skip
        self.passback.wake()
        return True

    def _catch_up_loop(self) -> None:
        """At start, at each graded announcement and every CATCH_UP_S: ask the grader
        (its lti role may read submissions) for the scores of the launched students
        since their first launch, and keep the ones it never had (a tool that was down
        or cut off catches up the same way).
        """
        while True:
            announced = self._graded.wait(self._catch_up_wait)
            self._graded.clear()
            if self._stop.is_set():
                return
            self._catch_up_wait = CATCH_UP_S
            try:
                self.catch_up(announced)
            except Exception:  # a lapsed login, the session closing: next time
                self.log.exception("catching up on missed scores failed")

    def catch_up(self, announced: bool = False) -> int:
        """Keep the scores not kept yet; ``announced``: the grader said one is graded."""
        grader = GraderClient(self.login.client, self.config.grader)
        kept = 0
        for user, assignment, since in self.store.launches():
            if self._stop.is_set():
                break
            try:
                found = grader.submissions(assignment, user=user)
            except LabError as exc:
                self.log.info("could not ask the grader for %s's scores: %s", user, exc)
                continue
            for s in sorted(found, key=lambda s: s.graded_at or 0.0):
                if s.status != "graded" or s.mean is None or s.graded_at is None:
                    continue
                if s.graded_at < since or self.store.known(s.submission):
                    continue
                if not announced:
                    self.log.info("score of %s was not announced to us: catching up", s.submission)
                kept += self._pass_back(
                    s.submission, user, assignment, s.mean - s.penalty, s.graded_at
                )
        return kept
