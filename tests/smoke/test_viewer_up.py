"""``wart up`` starts the viewer and prints the page's actual URL, which serves."""

from __future__ import annotations

import re
import urllib.request
from pathlib import Path

import pytest

from tests.kit.lab import UpLab

pytestmark = pytest.mark.smoke


def test_up_prints_the_viewer_url_and_it_serves(tmp_path: Path, realm: str) -> None:
    lab = UpLab(realm=realm, state_dir=tmp_path / "state").start()
    try:
        line = lab.wait_line("web viewer:", timeout=120)
        match = re.search(r"http://\S+", line)
        assert match, line
        assert match.group(0).endswith(f":{lab.http_port}")
        with urllib.request.urlopen(match.group(0), timeout=10) as reply:
            assert reply.status == 200
        lab.wait_line("The lab is running", timeout=60)
    finally:
        lab.stop()
