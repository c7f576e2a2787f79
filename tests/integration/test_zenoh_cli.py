"""An independent Zenoh client (the PyPI package zenoh-cli) sees our liveliness tokens.

This is the operator's check in docs/OPERATIONS.md: nothing about presence is
private to our own code.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from common import keys
from tests.conftest import Router


def zenoh_cli() -> str | None:
    beside = Path(sys.executable).with_name("zenoh")
    return str(beside) if beside.exists() else shutil.which("zenoh")


@pytest.mark.skipif(
    zenoh_cli() is None, reason="zenoh-cli is not installed (pip install zenoh-cli)"
)
def test_zenoh_cli_lists_the_router_token(router: Router) -> None:
    out = subprocess.run(
        [
            zenoh_cli(),
            "--mode",
            "client",
            "--connect",
            router.endpoint,
            "--cfg",
            "scouting/multicast/enabled:false",
            "liveliness",
            "get",
            "--key",
            keys.alive_all(router.realm),
        ],
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
    ).stdout
    tokens = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert {"key": f"wart/{router.realm}/alive/router/test-router", "status": "ALIVE"}.items() <= (
        tokens[0].items() if tokens else set()
    ), out
