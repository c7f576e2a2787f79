"""Helper program for the two-host test: a service (or a probe) on another host.

``python -m tests.integration.netns_service serve REALM ENDPOINT`` declares a
context token and answers a state query; ``probe REALM ENDPOINT`` waits for
that token, queries it, prints the answer and exits 0.
"""

from __future__ import annotations

import sys
import threading

import zenoh

from common import keys
from common.keys import AliveKind
from common.messages import OkReply, decode
from common.service import Service, close_session, open_session
from common.zconfig import NetworkOptions
from services.lab.supervisor import AliveWatch


class Remote(Service):
    kind = AliveKind.CONTEXT

    def on_start(self) -> None:
        self.serve(keys.ctx_state(self.realm, self.ident), self.answer)

    def answer(self, query: zenoh.Query) -> OkReply:
        return OkReply(detail="hello from the other host")


def main() -> int:
    role, realm, endpoint = sys.argv[1:4]
    session = open_session(NetworkOptions(realm=realm, connect=(endpoint,)), wait=20)
    try:
        if role == "serve":
            with Remote(session, realm, "remote"):
                print("serving", flush=True)
                threading.Event().wait(60)
            return 0
        watch = AliveWatch(session, keys.alive(realm, AliveKind.CONTEXT, "remote"))
        if not watch.wait(keys.alive(realm, AliveKind.CONTEXT, "remote"), 20):
            print("no token from the other host", flush=True)
            return 1
        for reply in session.get(keys.ctx_state(realm, "remote"), timeout=5):
            if reply.ok is not None:
                print("answer:", decode(reply.ok.payload, OkReply).detail, flush=True)
                return 0
        print("no answer", flush=True)
        return 1
    finally:
        close_session(session)


if __name__ == "__main__":
    sys.exit(main())
