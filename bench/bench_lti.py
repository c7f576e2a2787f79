"""A class launching the lab from its LMS at one instant (issue 36): LTI launches, p50 / p99.

A router, the registry and ``wart lti`` as processes, a fake LMS in this process
(tests/kit/lti_platform.py: its keys, JWKS, OIDC auth endpoint); ``--students``
launches, each as a browser makes it (the tool's login URL -> the platform's auth
page -> the signed launch posted to the tool -> the page's address with its
cookie), released by one barrier: first launches (each account made, put in the
course, a resume token minted), then the same students again (accounts matched).

    python -m bench.bench_lti [--students 60]
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from urllib.parse import urlencode

import psutil

from bench import cli as bench_cli
from bench.quantiles import percentile
from tests.kit.lab import make_lab
from tests.kit.lti_platform import CLIENT_ID, DEPLOYMENT, FakePlatform, form_fields
from tests.kit.lti_tool import start_lti
from tests.kit.procs import Procs, start_router, wart


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: object, **kwargs: object) -> None:
        return None


OPENER = urllib.request.build_opener(_NoRedirect)


def _status(request: urllib.request.Request | str) -> tuple[int, str, str]:
    try:
        with OPENER.open(request, timeout=60) as r:
            return r.status, r.headers.get("Location", ""), r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.headers.get("Location", ""), exc.read().decode()


def launch(tool: str, platform: str, sub: str) -> float:
    """One launch as a browser makes it; its wall time (s)."""
    start = time.perf_counter()
    query = {"iss": platform, "login_hint": f"sub:{sub}", "client_id": CLIENT_ID,
             "lti_deployment_id": DEPLOYMENT, "target_link_uri": f"{tool}/lti/launch"}  # fmt: skip
    status, auth, _ = _status(f"{tool}/lti/login?{urlencode(query)}")
    assert status == 303, status
    status, _, page = _status(auth)
    assert status == 200, page
    body = urlencode(form_fields(page)).encode()
    post = urllib.request.Request(
        f"{tool}/lti/launch",
        data=body,
        headers={"Content-Type": "application/x-www-form-urlencoded"},
        method="POST",
    )
    status, _, text = _status(post)
    assert status == 303, re.sub("<[^>]+>", " ", text)
    return time.perf_counter() - start


def burst(tool: str, platform: str, subs: list[str]) -> list[float]:
    barrier = threading.Barrier(len(subs))

    def one(sub: str) -> float:
        barrier.wait()
        return launch(tool, platform, sub)

    with ThreadPoolExecutor(len(subs)) as pool:
        return list(pool.map(one, subs))


def main() -> int:
    p = bench_cli.parser("bench_lti", __doc__)
    p.add_argument("--students", type=int, default=60)
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="wart-bench-lti-"))
    procs = Procs(tmp, env={"WART_LOG_LEVEL": os.environ.get("WART_BENCH_LOG_LEVEL", "WARNING")})
    platform = FakePlatform()
    try:
        router = start_router(procs, f"b{uuid.uuid4().hex[:8]}")
        lab = make_lab(router, procs, tmp)
        lab.start_registry()
        roster = tmp / "class.csv"
        roster.write_text("user,name,role\nida,Ida I,teacher\n")
        done = wart("users", "--db", str(lab.db_path), "import", str(roster), "--course",
                    "robotics-26")  # fmt: skip
        assert done.returncode == 0, done.stderr
        tool = start_lti(lab, tmp, platform)
        launch(tool, platform.url, "warm-up")  # the tool's first JWKS fetch, imports
        subs = [f"s{i:03}" for i in range(args.students)]
        print(f"{args.students} students launching at one instant "
              f"(load average {os.getloadavg()[0]:.1f}, {psutil.cpu_count()} cores)")  # fmt: skip
        for what in ("first launch: account made", "again: account matched"):
            t0 = time.perf_counter()
            times = burst(tool, platform.url, subs)
            wall = time.perf_counter() - t0
            print(f"  {what:28} p50 {percentile(times, 0.5):.2f} s  "
                  f"p99 {percentile(times, 0.99):.2f} s  "
                  f"max {max(times):.2f} s  (all in {wall:.2f} s)")  # fmt: skip
        return 0
    finally:
        platform.close()
        procs.stop_all()


if __name__ == "__main__":
    sys.exit(main())
