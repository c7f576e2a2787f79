"""Request and reply over Zenoh, written once: send a query, decode the answer, say what failed.

Every client of a lab service asks the same way: a get on the service's key
carrying the request (sealed with the asker's session when the service checks
who asks), the first answer decoded to the type expected, and everything that
can go wrong turned into one :class:`~common.lab_errors.LabError` whose text
says what was asked for:

- the service refused (it answered an ErrorReply): the LabError its code stands
  for (NotAllowed, NotFound, RateLimited...), "<what>: <the service's words>",
  with the ErrorReply in ``.reply``;
- nobody answered within the timeout (nothing serves the key, or what does was
  silent): :class:`NoReply`;
- the query could not be made (the session closing): :class:`QueryFailed`;
- the answer is not of the type asked for: :class:`WrongReply`.

A caller that tells its user something more precise ("is the registry
running?") catches the one it words differently; the decoding and the mapping
stay here. :func:`ask_all` is the companion for a key that many answer (every
host's load), :func:`admin_space` for the routers' admin space (JSON), and
:func:`alive_keys` for the liveliness tokens alive under a key.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar, cast

import zenoh

from common.lab_errors import LabError, refusal
from common.messages import ErrorCode, ErrorReply, Message, MessageError, decode, encode

M = TypeVar("M", bound=Message)

# A session's seal (common.auth.Session.seal): the request signed for the key it goes to.
Seal = Callable[[str, Message], bytes]


class NoReply(LabError):
    """Nobody answered within the timeout: nothing serves the key, or what does was silent."""

    def __init__(self, what: str, key: str, timeout: float) -> None:
        super().__init__(f"{what}: no answer on {key} within {timeout:g} s")
        self.key = key
        self.timeout = timeout


class QueryFailed(LabError):
    """The query could not be made (the session closed, the transport failed)."""

    def __init__(self, what: str, reason: str) -> None:
        super().__init__(f"{what}: {reason}")
        self.reason = reason  # Zenoh's own words


class WrongReply(LabError):
    """An answer that is not of the type asked for (another message, or not a message)."""


def ask(
    session: zenoh.Session,
    key: str,
    request: Message | None,
    expected: type[M] | tuple[type[M], ...],
    *,
    what: str,
    timeout: float,
    seal: Seal | None = None,
    source_info: zenoh.SourceInfo | None = None,
    kinds: Mapping[ErrorCode, type[LabError]] | None = None,
) -> M:
    """Send ``request`` (None: an empty query) to ``key``; the answer, of an ``expected`` type.

    ``what`` names the request in the user's words ("join lobby"), for every
    error's text. ``seal``: sign the request with the asker's session (the
    service verifies who asks); without it the request travels encoded only.
    ``source_info``: this session as the query's source (the registry keeps it
    in its audit trail). ``kinds``: the caller's own error class for some
    refusal codes. Raises a LabError, as the module says.
    """
    types = expected if isinstance(expected, tuple) else (expected,)
    wrong: MessageError | None = None
    for answer in _query(session, key, request, what, timeout, seal, source_info):
        try:
            reply = decode(answer, (*types, ErrorReply))
        except MessageError as exc:  # another replier may still say it right
            wrong = exc
            continue
        if isinstance(reply, ErrorReply):
            raise refusal(reply, what, kinds)
        return cast("M", reply)  # the decoder allowed only ``expected`` besides ErrorReply
    if wrong is not None:
        raise WrongReply(f"{what}: the answer on {key} is not usable: {wrong}")
    raise NoReply(what, key, timeout)


def ask_all(
    session: zenoh.Session,
    key: str,
    request: Message | None,
    expected: type[M],
    *,
    what: str,
    timeout: float,
) -> list[M]:
    """Every replier's answer of type ``expected`` (a wildcard key many serve), within
    ``timeout``; answers of another type are passed over. QueryFailed if the query
    cannot be made."""
    found = []
    options = {"target": zenoh.QueryTarget.ALL, "consolidation": zenoh.ConsolidationMode.NONE}
    for answer in _query(session, key, request, what, timeout, None, None, **options):
        try:
            found.append(decode(answer, expected))
        except MessageError:
            continue
    return found


def admin_space(
    session: zenoh.Session, key: str, *, what: str, timeout: float
) -> list[dict[str, Any]]:
    """Every answer of the routers' admin space under ``key`` (JSON, not a lab message),
    decoded; an answer that is not JSON is passed over. QueryFailed if the query cannot
    be made."""
    found = []
    options = {"target": zenoh.QueryTarget.ALL, "consolidation": zenoh.ConsolidationMode.NONE}
    for answer in _query(session, key, None, what, timeout, None, None, **options):
        try:
            found.append(json.loads(answer.to_bytes()))
        except ValueError:
            continue
    return found


def alive_keys(session: zenoh.Session, key_expr: str, *, what: str, timeout: float) -> list[str]:
    """The key expressions of the liveliness tokens alive now under ``key_expr`` (each
    token answers for itself); QueryFailed if the query cannot be made."""
    try:
        replies = session.liveliness().get(key_expr, timeout=timeout)
        return [str(reply.ok.key_expr) for reply in replies if reply.ok is not None]
    except zenoh.ZError as exc:
        raise QueryFailed(what, str(exc)) from None


def _query(
    session: zenoh.Session,
    key: str,
    request: Message | None,
    what: str,
    timeout: float,
    seal: Seal | None,
    source_info: zenoh.SourceInfo | None,
    **options: Any,
) -> Iterable[zenoh.ZBytes]:
    """The payloads of the answers, as they come; Zenoh's error replies (its timeout
    among them) are not answers."""
    payload = None
    if request is not None:
        payload = seal(key, request) if seal is not None else encode(request)
    try:
        for reply in session.get(
            key, payload=payload, timeout=timeout, source_info=source_info, **options
        ):
            if reply.ok is not None:
                yield reply.ok.payload
    except zenoh.ZError as exc:
        raise QueryFailed(what, str(exc)) from None
