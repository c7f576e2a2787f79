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
from common.ask import NoReply, QueryFailed, WrongReply, ask
from common.auth import AuthError, Verifier
from common.lab_errors import LabError
from common.messages import (
    DryRun,
    DryRunReport,
    Message,
    MessageError,
    OkReply,
    RunAccepted,
    RunCheck,
    RunCheckReply,
    RunClaim,
    RunRequest,
    RunStop,
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

    def start(self, job: ControlJob, ctx: str, world: str, end: float) -> tuple[bytes, bytes]:
        """The runner's session id and box key, once it accepted to run ``job`` until ``end``."""
        key = keys.runner_run(self.realm, self.runner)
        request = RunRequest(
            request_id=job.request_id,
            ctx=ctx,
            world=world,
            agent=job.agent,
            user=job.user,
            source=job.source,
            end=end,
            filename=job.filename,
        )
        try:
            reply = ask(
                self.session, key, request, RunAccepted, what="runner", timeout=10.0, seal=self.seal
            )
        except (NoReply, QueryFailed) as exc:
            self.log.warning("runner %s: %s", self.runner, exc)
            raise RequestError("unavailable", f"no runner {self.runner} answered") from None
        except WrongReply:
            raise RequestError("unavailable", "runner gave an unexpected reply") from None
        except LabError as exc:  # its refusal: "runner: why"
            raise RequestError("unavailable", str(exc)) from None
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
            return ask(
                self.session, key, request, DryRunReport, what="runner", timeout=timeout,
                seal=self.seal,
            )  # fmt: skip
        except NoReply:
            raise RequestError(
                "unavailable", f"no runner {self.runner} answered the dry run"
            ) from None
        except QueryFailed as exc:
            raise RequestError("unavailable", f"runner {self.runner}: {exc.reason}") from None
        except WrongReply as exc:
            self.log.warning("unreadable dry-run reply: %s", exc)
            raise RequestError(
                "unavailable", f"no runner {self.runner} answered the dry run"
            ) from None
        except LabError as exc:  # its refusal: "runner: why"
            reply = exc.reply
            if reply is not None and reply.code == "bad_request":
                raise RequestError("bad_request", str(exc)) from None
            retry = 0.0 if reply is None else reply.retry_after
            raise RequestError("unavailable", str(exc), retry) from None

    def stop(self, request_id: str, reason: str) -> None:
        """Tell the runner to end the request's sandbox (best effort: the lease ends anyway)."""
        key = keys.runner_run(self.realm, self.runner)
        request = RunStop(request_id=request_id, reason=reason)
        try:
            ask(self.session, key, request, OkReply, what="runner", timeout=2.0, seal=self.seal)
        except LabError as exc:
            self.log.warning("runner %s: %s", self.runner, exc)

    def still_running(self, request_ids: list[str], timeout: float) -> set[str] | None:
        """Those of ``request_ids`` the runner runs now; None when no runner answered."""
        key = keys.runner_run(self.realm, self.runner)
        request = RunCheck(request_ids=request_ids)
        try:
            reply = ask(
                self.session, key, request, RunCheckReply, what="runner", timeout=timeout,
                seal=self.seal,
            )  # fmt: skip
        except LabError as exc:
            if getattr(exc, "reply", None) is not None:
                self.log.warning("runner %s could not say what it runs: %s", self.runner, exc)
            return None
        return set(reply.running)

    def driver(self, request_id: str, default: str) -> str:
        """The runner account driving ``request_id`` (``default`` before it accepted)."""
        return self._drivers.get(request_id, default)

    def forget(self, request_id: str) -> None:
        self._drivers.pop(request_id, None)
