"""A request of the wrong type, sealed by a real session, is refused in words at once,
not at the asker's timeout (a real router and registry)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from common import keys
from common.ask import ask
from common.lab_errors import LabError
from common.messages import ChatSay, OkReply
from tests.conftest import Procs, Router
from tests.kit.lab import make_lab


def test_a_sealed_request_of_the_wrong_type_is_refused_at_once(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    r = lab.realm
    served = (
        keys.registry_logout,
        keys.registry_directory,
        keys.registry_admin,
        keys.registry_twins,
    )
    with lab.client("alice") as alice:
        assert alice.session is not None
        for key in (*(k(r) for k in served), keys.registry_audit(r), keys.registry_lti(r)):
            t0 = time.monotonic()
            with pytest.raises(LabError, match="not a valid"):
                ask(alice.z, key, ChatSay(text="hi"), OkReply, what="ask", timeout=5.0,
                    seal=alice.session.seal)  # fmt: skip
            assert time.monotonic() - t0 < 2.0, key  # before: 5.0 s, the timeout, each
