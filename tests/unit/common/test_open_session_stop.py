"""A service waiting for its router stops when told to (SIGTERM used to be ignored there)."""

from __future__ import annotations

import threading

from common.service import open_session
from common.zconfig import NetworkOptions
from tests.conftest import free_port


def test_waiting_for_an_absent_router_ends_when_stop_is_set() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    options = NetworkOptions(realm="tstop", mode="client", connect=(endpoint,))
    stop = threading.Event()
    raised: list[Exception] = []

    def waiting() -> None:
        try:
            open_session(options, stop=stop, quiet=True)  # wait=None: only stop ends it
        except ConnectionError as exc:
            raised.append(exc)

    waiter = threading.Thread(target=waiting, daemon=True)
    waiter.start()
    stop.set()
    waiter.join(30)  # it looped on for ever before
    assert not waiter.is_alive()
    assert raised and "stopped while waiting" in str(raised[0])
