"""An agent context's line to its runner: start a deployed controller, stop it.

The runner answers a sealed :class:`~common.messages.RunRequest` with a
:class:`~common.messages.RunAccepted` carrying a claim it signed with its own
session; the lease then names that session as the holder. The context checks
the claim (the ``run`` permission, the same request) before trusting it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import zenoh

from common import keys
from common.auth import AuthError, Verifier
from common.messages import (
    DryRun,
    DryRunReport,
    ErrorReply,
    Message,
    MessageError,
    OkReply,
    RunAccepted,
    RunCheck,
    RunCheckReply,
    RunClaim,
    RunRequest,
    RunStop,
    decode,
)
from common.service import RequestError
from services.context.agent_queue import ControlJob

Seal = Callable[[str, Message], bytes]  # the context's current session seals for a key


class RunnerLink:
    """Requests to runner ``runner`` and who (which runner account) drives each request."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        runner: str,
        seal: Seal,
        verifier: Verifier,
        log: logging.Logger,
    ) -> None:
        self.session = session
        self.realm = realm
        self.runner = keys.check_ident("runner", runner)
        self.seal = seal
        self.verifier = verifier
        self.log = log
        self._drivers: dict[str, str] = {}  # request id -> the runner account driving it

    def ask(self, message: Message, timeout: float) -> Message | None:
        """The runner's reply, or None when none answered (or it was unreadable)."""
        key = keys.runner_run(self.realm, self.runner)
        try:
            replies = list(self.session.get(key, payload=self.seal(key, message), timeout=timeout))
        except Exception as exc:
            self.log.warning("runner %s: %s", self.runner, exc)
            return None
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                return decode(reply.ok.payload, (RunAccepted, OkReply, RunCheckReply, ErrorReply))
            except MessageError as exc:
                self.log.warning("unreadable runner reply: %s", exc)
        return None

    def start(self, job: ControlJob, ctx: str, world: str, end: float) -> tuple[bytes, bytes]:
        """The runner's session id and box key, once it accepted to run ``job`` until ``end``."""
        key = keys.runner_run(self.realm, self.runner)
        reply = self.ask(
            RunRequest(
                request_id=job.request_id,
                ctx=ctx,
                world=world,
                agent=job.agent,
                user=job.user,
                source=job.source,
                end=end,
                filename=job.filename,
            ),
            timeout=10.0,
        )
        if reply is None:
            raise RequestError("unavailable", f"no runner {self.runner} answered")
        if isinstance(reply, ErrorReply):
            raise RequestError("unavailable", f"runner: {reply.message}")
        if not isinstance(reply, RunAccepted):
            raise RequestError("unavailable", "runner gave an unexpected reply")
        try:
            principal, claim = self.verifier.open(key, reply.claim, RunClaim)
        except (AuthError, MessageError) as exc:
            raise RequestError("unavailable", f"runner's claim refused: {exc}") from None
        if not principal.has("run") or claim.request_id != job.request_id:
            raise RequestError("unavailable", f"{principal.user} may not run controllers")
        self._drivers[job.request_id] = principal.user
        return principal.session_id, principal.token.box_key

    def dry_run(self, request: DryRun, timeout: float) -> DryRunReport:
        """The runner's report of a dry run; RequestError if it gave none.

        The report is not signed: on a lab with access control only runners may
        serve the key; on an open one a fake report only misleads its requester.
        """
        key = keys.runner_dryrun(self.realm, self.runner)
        try:
            replies = list(self.session.get(key, payload=self.seal(key, request), timeout=timeout))
        except Exception as exc:
            raise RequestError("unavailable", f"runner {self.runner}: {exc}") from None
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                answer = decode(reply.ok.payload, (DryRunReport, ErrorReply))
            except MessageError as exc:
                self.log.warning("unreadable dry-run reply: %s", exc)
                continue
            if isinstance(answer, ErrorReply):
                if answer.code == "bad_request":
                    raise RequestError("bad_request", f"runner: {answer.message}")
                raise RequestError("unavailable", f"runner: {answer.message}", answer.retry_after)
            assert isinstance(answer, DryRunReport)  # the decoder allowed only these two
            return answer
        raise RequestError("unavailable", f"no runner {self.runner} answered the dry run")

    def stop(self, request_id: str, reason: str) -> None:
        """Tell the runner to end the request's sandbox (best effort: the lease ends anyway)."""
        self.ask(RunStop(request_id=request_id, reason=reason), timeout=2.0)

    def still_running(self, request_ids: list[str], timeout: float) -> set[str] | None:
        """Those of ``request_ids`` the runner runs now; None when no runner answered."""
        reply = self.ask(RunCheck(request_ids=request_ids), timeout=timeout)
        if isinstance(reply, RunCheckReply):
            return set(reply.running)
        if isinstance(reply, ErrorReply):
            self.log.warning("runner %s could not say what it runs: %s", self.runner, reply.message)
        return None

    def driver(self, request_id: str, default: str) -> str:
        """The runner account driving ``request_id`` (``default`` before it accepted)."""
        return self._drivers.get(request_id, default)

    def forget(self, request_id: str) -> None:
        self._drivers.pop(request_id, None)
