"""Two hosts in network namespaces: a router on one, a service on the other, talking."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.kit import netns

pytestmark = pytest.mark.netns

_reason = netns.available()


@pytest.mark.skipif(_reason is not None, reason=f"two-host test skipped: {_reason}")
def test_service_on_host_b_answers_a_client_on_host_a_through_a_router(
    tmp_path: Path, realm: str
) -> None:
    with netns.Network(2) as net:
        a, b = net.hosts
        endpoint = f"tcp/{a.address}:7447"
        router = a.popen(
            ["-m", "services.cli", "router", "--realm", realm, "--listen", endpoint],
            tmp_path / "router.log",
        )
        service = b.popen(
            ["-m", "tests.integration.netns_service", "serve", realm, endpoint],
            tmp_path / "service.log",
        )
        probe = a.popen(
            ["-m", "tests.integration.netns_service", "probe", realm, f"tcp/{a.address}:7447"],
            tmp_path / "probe.log",
        )
        try:
            code = probe.wait(60)
            out = (tmp_path / "probe.log").read_text()
            assert code == 0, out + (tmp_path / "service.log").read_text()
            assert "answer: hello from the other host" in out
        finally:
            for proc in (service, router, probe):
                if proc.poll() is None:
                    proc.terminate()
                    try:
                        proc.wait(10)
                    except Exception:
                        proc.kill()
