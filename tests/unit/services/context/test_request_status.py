"""The agent context's request-status answer: who may read it, and what it says."""

from __future__ import annotations

from typing import Any

import pytest

from common import keys
from common.auth import AuthError, RegistryIdentity, Session, Verifier, issue_session
from common.keys import AliveKind
from common.messages import (
    ErrorReply,
    MessageError,
    QueueStateRequest,
    RequestStatus,
    RequestStatusQuery,
    RequestStatusReply,
    decode,
)
from common.service import RequestError, Service
from services.context.agent_queue import ControlJob, QueueBook, RunningJob, load_book, save_book
from services.context.request_status import RequestStatusDesk, look_up

REALM = "lab"
CTX = "arena"
KEY = keys.ctx_status(REALM, CTX)
STUDENT = ["join", "chat", "control", "deploy"]
NOW = 1000.0


@pytest.fixture
def identity() -> RegistryIdentity:
    return RegistryIdentity.generate()


def job(rid: str, user: str = "alice", agent: str = "k1") -> ControlJob:
    return ControlJob(request_id=rid, agent=agent, user=user, session_id=b"s" * 16, mode="deploy")


@pytest.fixture
def book() -> QueueBook:
    """k1 runs alice's r-run until NOW + 30, alice's r-wait waits behind bob's r-bob."""
    book = QueueBook(slot_seconds=60)
    book.set_agents({"k1": "khepera"})
    running = job("r-run")
    book.lines["k1"].running = RunningJob(running, "L", b"s" * 16, start=NOW - 30, end=NOW + 30)
    book.add(job("r-bob", user="bob"))
    book.add(job("r-wait"))
    book.record_end(
        RequestStatus(
            request_id="r-gone",
            agent="k1",
            user="alice",
            status="cancelled",
            reason="the lab's runner runner stopped (crashed or restarted)",
            start=NOW - 100,
            end=NOW - 40,
        ),
        NOW - 40,
    )
    return book


def desk_of(
    identity: RegistryIdentity, book: QueueBook, starting: dict[str, ControlJob]
) -> RequestStatusDesk:
    return RequestStatusDesk(
        CTX,
        "ida",  # the context's owner
        Verifier(identity.verify_key, REALM),
        lambda rid: look_up(book, starting, rid, NOW),
    )


def ask(desk: RequestStatusDesk, session: Session, request_id: str) -> RequestStatusReply:
    return desk.answer(KEY, session.seal(KEY, RequestStatusQuery(request_id=request_id)))


def test_the_owner_of_a_request_reads_where_it_stands(
    identity: RegistryIdentity, book: QueueBook
) -> None:
    alice = issue_session(identity, REALM, "alice", STUDENT)
    desk = desk_of(identity, book, {"r-next": job("r-next")})

    running = ask(desk, alice, "r-run")
    assert running.status is not None and running.status.status == "running"
    assert running.status.end is not None and running.status.end - running.at == 30  # time left

    queued = ask(desk, alice, "r-wait")
    assert queued.status is not None and queued.status.status == "queued"
    assert (queued.position, queued.start_eta) == (2, NOW + 30 + 60)

    starting = ask(desk, alice, "r-next")  # off its queue, the runner being asked
    assert starting.status is not None and starting.status.status == "queued"
    assert starting.position == 1

    ended = ask(desk, alice, "r-gone")
    assert ended.ended and ended.status is not None
    assert ended.status.status == "cancelled" and "runner runner stopped" in ended.status.reason
    assert ended.ended_at == NOW - 40


def test_another_student_is_refused_another_users_request(
    identity: RegistryIdentity, book: QueueBook
) -> None:
    bob = issue_session(identity, REALM, "bob", STUDENT)
    desk = desk_of(identity, book, {})
    for rid in ("r-run", "r-wait", "r-gone"):
        with pytest.raises(RequestError, match=f"request {rid} is alice's") as refused:
            ask(desk, bob, rid)
        assert refused.value.code == "forbidden"
    assert ask(desk, bob, "r-bob").position == 1  # his own he reads


@pytest.mark.parametrize(
    ("user", "permissions", "grants"),
    [
        ("ida", STUDENT, None),  # the context's owner
        ("carol", [*STUDENT, "kick"], None),  # an instructor: kick everywhere
        ("dave", STUDENT, {"ctx/arena": ["kick"]}),  # kick here
    ],
)
def test_the_contexts_managers_read_anyones(
    identity: RegistryIdentity,
    book: QueueBook,
    user: str,
    permissions: list[str],
    grants: dict[str, list[str]] | None,
) -> None:
    manager = issue_session(identity, REALM, user, permissions, grants=grants)
    reply = ask(desk_of(identity, book, {}), manager, "r-gone")
    assert reply.status is not None and reply.status.user == "alice"


def test_kick_in_another_context_does_not_make_a_manager(
    identity: RegistryIdentity, book: QueueBook
) -> None:
    elsewhere = issue_session(identity, REALM, "erin", STUDENT, grants={"ctx/lobby": ["kick"]})
    with pytest.raises(RequestError, match="is alice's"):
        ask(desk_of(identity, book, {}), elsewhere, "r-run")


def test_an_unknown_id_is_unknown_to_anyone_and_tells_nothing(
    identity: RegistryIdentity, book: QueueBook
) -> None:
    desk = desk_of(identity, book, {})
    for user in ("alice", "bob", "ida"):
        reply = ask(desk, issue_session(identity, REALM, user, STUDENT), "k1-99-abcdef")
        assert reply == RequestStatusReply(request_id="k1-99-abcdef", at=NOW)
        assert not reply.known and not reply.ended


def test_without_join_nothing_is_answered(identity: RegistryIdentity, book: QueueBook) -> None:
    outsider = issue_session(identity, REALM, "alice", ["chat"])
    with pytest.raises(AuthError, match="'join' permission") as refused:
        ask(desk_of(identity, book, {}), outsider, "r-run")
    assert refused.value.code == "forbidden"


def test_malformed_queries_are_refused_clearly(identity: RegistryIdentity, book: QueueBook) -> None:
    alice = issue_session(identity, REALM, "alice", STUDENT)
    desk = desk_of(identity, book, {})
    # msgspec checks constraints on decoding, not on building: this one is sealed as is.
    bad_id = alice.seal(KEY, RequestStatusQuery(request_id="../other"))
    with pytest.raises(MessageError, match=r"RequestStatusQuery.*request_id"):
        desk.answer(KEY, bad_id)
    with pytest.raises(MessageError, match="RequestStatusQuery"):
        desk.answer(KEY, alice.seal(KEY, QueueStateRequest()))  # another request type
    with pytest.raises((AuthError, MessageError)):
        desk.answer(KEY, b"\x93not an envelope")
    # sealed for another context's key: the signature covers the key
    elsewhere = keys.ctx_status(REALM, "lobby")
    with pytest.raises(AuthError, match="signature"):
        desk.answer(KEY, alice.seal(elsewhere, RequestStatusQuery(request_id="r-run")))
    assert ask(desk, alice, "r-run").known  # and it goes on answering


class _Query:
    def __init__(self, payload: bytes) -> None:
        self.key_expr = KEY
        self.payload = payload
        self.replies: list[bytes] = []

    def reply(self, _key: str, payload: bytes) -> None:
        self.replies.append(payload)


class _Session:
    """Just enough of a Zenoh session for Service.serve: it hands back the callback."""

    def __init__(self) -> None:
        self.handlers: dict[str, Any] = {}

    def declare_queryable(self, key: str, handler: Any) -> Any:
        self.handlers[key] = handler
        return object()  # the declaration's handle; never undeclared here


class _Context(Service):
    kind = AliveKind.CONTEXT


def test_through_the_service_bad_input_is_an_error_reply_and_serving_goes_on(
    identity: RegistryIdentity, book: QueueBook
) -> None:
    session = _Session()
    service = _Context(session, REALM, CTX)  # type: ignore[arg-type]
    desk = desk_of(identity, book, {})
    service.serve(KEY, lambda q: desk.answer(str(q.key_expr), q.payload))
    serve = session.handlers[KEY]
    alice = issue_session(identity, REALM, "alice", STUDENT)
    bob = issue_session(identity, REALM, "bob", STUDENT)

    answers = []
    for payload in (
        b"garbage",
        alice.seal(KEY, RequestStatusQuery(request_id="bad id!")),
        bob.seal(KEY, RequestStatusQuery(request_id="r-gone")),
        alice.seal(KEY, RequestStatusQuery(request_id="r-gone")),
    ):
        query = _Query(payload)
        serve(query)
        (reply,) = query.replies
        answers.append(decode(reply, (RequestStatusReply, ErrorReply)))
    garbage, bad_id, others, mine = answers
    assert isinstance(garbage, ErrorReply) and garbage.code in ("bad_request", "unauthenticated")
    assert isinstance(bad_id, ErrorReply) and bad_id.code == "bad_request"
    assert "request_id" in bad_id.message
    assert isinstance(others, ErrorReply) and others.code == "forbidden"
    assert isinstance(mine, RequestStatusReply) and mine.status is not None
    assert mine.status.reason.startswith("the lab's runner runner stopped")


def test_the_record_of_ended_requests_survives_a_restart(book: QueueBook) -> None:
    restored = load_book(save_book(book))
    reply = look_up(restored, {}, "r-gone", NOW)
    assert reply.status is not None and "runner runner stopped" in reply.status.reason
