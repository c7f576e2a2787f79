"""``wart probe``: Kubernetes' probes read the lab's liveliness tokens through a real router."""

from __future__ import annotations

import zenoh

from common import keys
from common.keys import AliveKind
from tests.kit.procs import Router, free_port, wart


def test_probe_passes_while_the_token_is_there_and_says_why_not_when_it_goes(
    router: Router, zsession: zenoh.Session
) -> None:
    net = router.net_args()
    token = zsession.liveliness().declare_token(keys.alive(router.realm, AliveKind.WORLD, "w1"))
    ready = wart("probe", "world", "w1", *net)
    assert ready.returncode == 0, ready.stderr
    assert "world w1 is alive" in ready.stdout
    token.undeclare()
    gone = wart("probe", "world", "w1", *net)
    assert gone.returncode == 1
    assert f"no token wart/{router.realm}/alive/world/w1" in gone.stderr
    # Its token gone while the router answers: a liveness failure too (restart the pod).
    assert wart("probe", "world", "w1", "--liveness", *net).returncode == 1


def test_no_router_is_unready_but_alive() -> None:
    nowhere = ["--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1"]
    unready = wart("probe", "registry", "registry", *nowhere)
    assert unready.returncode == 2 and "not ready: no Zenoh router reachable" in unready.stderr
    # A router being replaced is no reason to restart every pod that uses it.
    alive = wart("probe", "registry", "registry", "--liveness", *nowhere)
    assert alive.returncode == 0 and "not this service's fault" in alive.stdout
    bad = wart("probe", "world", "no/such", *nowhere)
    assert bad.returncode == 2 and "error:" in bad.stderr and "no/such" in bad.stderr
