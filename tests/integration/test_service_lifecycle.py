"""A service on a real router: its token is seen while it serves, and gone once it stops."""

from __future__ import annotations

import zenoh

from common import keys
from common.keys import AliveKind
from common.messages import ErrorReply, OkReply, decode
from common.service import RequestError, Service, close_session, open_session
from services.lab.supervisor import AliveWatch
from tests.conftest import Router, wait_for
from tests.kit.procs import start_router


class Echo(Service):
    kind = AliveKind.CONTEXT

    def on_start(self) -> None:
        self.serve(keys.ctx_state(self.realm, self.ident), self.answer)

    def answer(self, query: zenoh.Query) -> OkReply:
        if query.payload is not None and query.payload.to_bytes() == b"fail":
            raise RequestError("not_found", "no such thing")
        if query.payload is not None and query.payload.to_bytes() == b"crash":
            raise RuntimeError("a bug")
        return OkReply(detail="hello")


def ask(session: zenoh.Session, key: str, payload: bytes) -> object:
    for reply in session.get(key, payload=payload, timeout=5.0):
        assert reply.ok is not None
        return decode(reply.ok.payload, (OkReply, ErrorReply))
    raise AssertionError("no reply")


def test_token_seen_while_serving_and_gone_after_stop(
    router: Router, alive_watch: AliveWatch
) -> None:
    session = open_session(router.options(), wait=10.0)
    key = keys.alive(router.realm, AliveKind.CONTEXT, "echo")
    try:
        service = Echo(session, router.realm, "echo").start()
        assert alive_watch.wait(key, 10.0), "the service's liveliness token never appeared"
        service.stop()
        wait_for(lambda: not alive_watch.present(key), 10.0, "the token to disappear")
    finally:
        close_session(session)


def test_query_errors_become_error_replies_and_service_keeps_serving(
    router: Router, zsession: zenoh.Session, alive_watch: AliveWatch
) -> None:
    session = open_session(router.options(), wait=10.0)
    try:
        with Echo(session, router.realm, "echo") as echo:
            # The token is declared after the queryable: once it is seen, queries reach it.
            assert alive_watch.wait(echo.alive_key, 10.0)
            key = keys.ctx_state(router.realm, "echo")
            not_found = ask(zsession, key, b"fail")
            assert isinstance(not_found, ErrorReply) and not_found.code == "not_found"
            crashed = ask(zsession, key, b"crash")
            assert isinstance(crashed, ErrorReply) and crashed.code == "internal"
            fine = ask(zsession, key, b"ok")
            assert fine == OkReply(detail="hello")
    finally:
        close_session(session)


def test_killed_process_token_disappears(router: Router, procs, alive_watch: AliveWatch) -> None:
    key = keys.alive(router.realm, AliveKind.ROUTER, "second")
    # A second router meshed with the first, as another host's would be.
    second = start_router(
        procs, router.realm, "second", connect=[router.endpoint], log_name="second-router"
    )
    proc = second.proc
    assert alive_watch.wait(key, 20.0), proc.output()
    proc.kill9()
    wait_for(lambda: not alive_watch.present(key), 15.0, "a killed router's token to go")
