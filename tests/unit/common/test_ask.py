"""ask(): one request and reply through a real Zenoh router, and what its caller is told."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
import zenoh

from common import keys
from common.ask import NoReply, QueryFailed, WrongReply, admin_space, alive_keys, ask, ask_all
from common.auth import AuthError, RegistryIdentity, Verifier, issue_session
from common.lab_errors import LabError, NotAllowed, RequestFailed
from common.messages import DirectoryRequest, ErrorReply, OkReply, decode, encode
from common.service import close_session, open_session
from tests.conftest import Router, wait_for

pytestmark = pytest.mark.shared_router


@pytest.fixture
def replier(router: Router) -> Iterator[zenoh.Session]:
    """A second session through the router: the service side of each test."""
    session = open_session(router.options(), wait=10.0)
    yield session
    close_session(session)


Answer = Callable[[zenoh.Query], bytes | None]


@pytest.fixture
def serve(
    replier: zenoh.Session, zsession: zenoh.Session
) -> Iterator[Callable[[str, Answer], None]]:
    """Serve ``key`` from the replier with ``answer`` (None: keep silent); return once the
    asking session can reach it (a token declared after the queryable is seen)."""
    handles: list[zenoh.Queryable | zenoh.LivelinessToken] = []
    held: list[zenoh.Query] = []

    def declare(key: str, answer: Answer) -> None:
        def on_query(query: zenoh.Query) -> None:
            payload = answer(query)
            if payload is None:
                held.append(query)  # kept, so the query is not finalised at once
            else:
                query.reply(query.key_expr, payload)

        handles.append(replier.declare_queryable(key, on_query))
        handles.append(replier.liveliness().declare_token(key + "/up"))
        wait_for(
            lambda: any(r.ok for r in zsession.liveliness().get(key + "/up", timeout=1.0)),
            what=f"{key} served",
        )

    yield declare
    held.clear()
    for handle in handles:
        handle.undeclare()


def test_the_reply_comes_back_decoded_to_its_type(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    key = f"{realm}/svc/hello"
    serve(key, lambda q: encode(OkReply(detail=f"hello {decode(q.payload, DirectoryRequest).v}")))
    reply = ask(zsession, key, DirectoryRequest(), OkReply, what="greet", timeout=5.0)
    assert isinstance(reply, OkReply)
    assert reply.detail == "hello 1"


def test_an_error_reply_is_raised_with_its_words_and_what_was_asked(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    key = f"{realm}/svc/closed"
    serve(key, lambda q: encode(ErrorReply(code="forbidden", message="members only")))
    with pytest.raises(NotAllowed, match=r"^join lobby: members only$") as raised:
        ask(zsession, key, DirectoryRequest(), OkReply, what="join lobby", timeout=5.0)
    assert raised.value.reply is not None and raised.value.reply.code == "forbidden"


def test_a_callers_own_error_class_for_a_code(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    class Taken(RequestFailed):
        pass

    key = f"{realm}/svc/spawn"
    serve(key, lambda q: encode(ErrorReply(code="conflict", message="arena7 runs already")))
    with pytest.raises(Taken, match=r"^host h1: arena7 runs already$"):
        ask(
            zsession,
            key,
            DirectoryRequest(),
            OkReply,
            what="host h1",
            timeout=5.0,
            kinds={"conflict": Taken},
        )


def test_nobody_serving_the_key_is_no_reply_naming_what_was_asked(
    zsession: zenoh.Session, realm: str
) -> None:
    key = f"{realm}/svc/nobody"
    with pytest.raises(NoReply, match=rf"^directory: no answer on {key} within 2 s$") as raised:
        ask(zsession, key, DirectoryRequest(), OkReply, what="directory", timeout=2.0)
    assert isinstance(raised.value, LabError)


def test_a_silent_replier_is_no_reply_after_the_timeout(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    key = f"{realm}/svc/silent"
    serve(key, lambda q: None)
    started = time.monotonic()
    with pytest.raises(NoReply, match=r"^silence: no answer on .* within 0.5 s$"):
        ask(zsession, key, None, OkReply, what="silence", timeout=0.5)
    assert time.monotonic() - started >= 0.4  # waited for it, not given up at once


def test_a_reply_of_another_type_is_refused_clearly(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    key = f"{realm}/svc/confused"
    serve(key, lambda q: encode(DirectoryRequest()))
    with pytest.raises(WrongReply, match=r"^logout: the answer on .* is not usable: .*OkReply"):
        ask(zsession, key, DirectoryRequest(), OkReply, what="logout", timeout=5.0)


def test_a_closed_session_is_a_failed_query(router: Router, realm: str) -> None:
    session = open_session(router.options(), wait=10.0)
    close_session(session)
    with pytest.raises(QueryFailed, match=r"^directory: ") as raised:
        ask(session, f"{realm}/svc/any", None, OkReply, what="directory", timeout=1.0)
    assert raised.value.reason


def test_a_sealed_request_is_accepted_by_a_verifying_queryable(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    registry = RegistryIdentity.generate()
    verifier = Verifier(registry.verify_key, realm)
    alice = issue_session(registry, realm, "alice", ["chat"])
    key = f"{realm}/svc/who"

    def answer(query: zenoh.Query) -> bytes:
        try:
            principal, _ = verifier.open(str(query.key_expr), query.payload, DirectoryRequest)
        except AuthError as exc:
            return encode(ErrorReply(code=exc.code, message=exc.message))
        return encode(OkReply(detail=principal.user))

    serve(key, answer)
    reply = ask(
        zsession, key, DirectoryRequest(), OkReply, what="who", timeout=5.0, seal=alice.seal
    )
    assert reply.detail == "alice"
    with pytest.raises(LabError, match=r"^who: "):  # the same request unsealed is refused
        ask(zsession, key, DirectoryRequest(), OkReply, what="who", timeout=5.0)


def test_ask_all_gathers_every_repliers_answer(
    zsession: zenoh.Session, serve: Callable[[str, Answer], None], realm: str
) -> None:
    for host in ("h1", "h2"):
        serve(f"{realm}/host/{host}/load", lambda q, h=host: encode(OkReply(detail=h)))
    serve(f"{realm}/host/h3/load", lambda q: encode(DirectoryRequest()))  # passed over
    found = ask_all(
        zsession, f"{realm}/host/*/load", DirectoryRequest(), OkReply, what="loads", timeout=3.0
    )
    assert sorted(r.detail for r in found) == ["h1", "h2"]


def test_alive_keys_lists_the_live_tokens_and_a_closed_session_fails(
    router: Router, zsession: zenoh.Session, replier: zenoh.Session, realm: str
) -> None:
    tokens = [replier.liveliness().declare_token(f"{realm}/alive/runner/{n}") for n in "ab"]
    key = f"{realm}/alive/runner/*"

    def alive() -> list[str]:
        return sorted(alive_keys(zsession, key, what="runners", timeout=2.0))

    wait_for(lambda: len(alive()) == 2, what="both tokens")
    assert alive() == [f"{realm}/alive/runner/a", f"{realm}/alive/runner/b"]
    for token in tokens:
        token.undeclare()
    closed = open_session(router.options(), wait=10.0)
    close_session(closed)
    with pytest.raises(QueryFailed, match=r"^runners: "):
        alive_keys(closed, key, what="runners", timeout=1.0)


def test_admin_space_gives_the_routers_views(zsession: zenoh.Session) -> None:
    views = admin_space(zsession, keys.routers_admin_all(), what="routers", timeout=3.0)
    assert len(views) == 1 and views[0]["zid"]  # the test's one router
    own = admin_space(zsession, keys.router_admin(views[0]["zid"]), what="router", timeout=3.0)
    assert own and own[0]["locators"]
