"""A class logging in at one instant: 60 clients, p50 / p99, with and without resume tokens.

A router and the registry as ``wart`` processes (real argon2id checks at the
registry's parameters); ``--clients`` students (accounts s00, s01, ...), each a
LabClient on its own Zenoh session in this process, released by one barrier:

1. password logins, every client at the same instant (each asks for a resume token);
2. the same clients log out of nothing and resume with their token, at one instant
   (a browser reloading the page: no password check);
3. password logins again, at one instant.

A password user's client derives its mailbox key from the password (argon2id, as
costly as the registry's check). ``--derive``:

- ``elsewhere`` (default): on the students' own machines (done before the clock starts);
- ``before``: on this machine, before asking the registry (the web page until issue 38:
  the viewer derived it for each browser on the lab's cores);
- ``after``: on this machine, after the login, at the lowest CPU priority (the page now:
  viewers/web/connector.py); the login's time stops at the registry's answer.

    python -m bench.bench_login_burst [--clients 60] [--derive after]
"""

from __future__ import annotations

import functools
import os
import queue
import statistics
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import psutil
import zenoh

from bench import cli as bench_cli
from bench.labproc import BenchLab
from bench.quantiles import percentile
from common.client import lab_client as client_module
from common.client.lab_client import LabClient
from common.service import close_session, open_session

PASSWORD = "class-of-2026"


def _claim_low(clients: Iterator[LabClient]) -> None:
    """As the viewer does (viewers/web/connector.py MailboxClaims): one at a time, nice 19."""
    os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
    for client in clients:
        client.claim_mailbox(PASSWORD)


def _burst(
    clients: list[LabClient], how: str, resumes: dict[int, bytes], derive: str
) -> tuple[list[float], int]:
    """Every client logs in at one instant; (each one's wait in s, failures)."""
    start = threading.Barrier(len(clients))
    failed = 0
    lock = threading.Lock()

    def one(i: int) -> float:
        nonlocal failed
        client = clients[i]
        user = f"s{i:02d}"
        start.wait()
        t0 = time.perf_counter()
        try:
            if how == "resume":
                client.resume(resumes[i])
            else:
                client.login(user, PASSWORD, resume=True, defer_mailbox=derive == "after")
        except Exception as exc:
            with lock:
                failed += 1
            print(f"  {user}: {type(exc).__name__}: {exc}", flush=True)
        took = time.perf_counter() - t0
        if client.resume_token is not None:
            resumes[i] = client.resume_token
        if how == "password" and derive == "after" and client.session is not None:
            claims.put(client)
        return took

    claims: queue.SimpleQueue[LabClient | None] = queue.SimpleQueue()
    worker = threading.Thread(target=_claim_low, args=(iter(claims.get, None),))
    worker.start()
    with ThreadPoolExecutor(len(clients)) as pool:
        waits = list(pool.map(one, range(len(clients))))
    claims.put(None)
    worker.join()  # every mailbox claimed before the next burst
    return waits, failed


def _cpu(proc: psutil.Process) -> float:
    times = proc.cpu_times()
    return float(times.user + times.system)


def main() -> int:
    ap = bench_cli.parser("bench_login_burst", __doc__)
    ap.add_argument("--clients", type=int, default=60)
    ap.add_argument("--derive", choices=("elsewhere", "before", "after"), default="elsewhere")
    args = ap.parse_args()
    if not 0 < args.clients <= 200:
        ap.error("--clients 1..200")
    n = args.clients
    print(f"load average before {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs", flush=True)
    users = [f"s{i:02d}" for i in range(n)]
    lab = BenchLab(users, PASSWORD)
    sessions: list[zenoh.Session] = []
    derive = client_module.mailbox_key_from_password
    try:
        lab.start()
        sessions = [open_session(lab.options, wait=10.0) for _ in range(n)]
        clients = [
            LabClient(s, lab.realm, lab.identity.verify_key, presence=False) for s in sessions
        ]
        if args.derive == "elsewhere":
            cached = functools.cache(derive)
            for user in users:
                cached(lab.realm, user, PASSWORD)
            client_module.mailbox_key_from_password = cached
        where = {
            "elsewhere": "on the students' machines",
            "before": "here, before asking",
            "after": "here, after the login at nice 19",
        }[args.derive]
        print(f"{n} clients at one instant; mailbox keys derived {where}", flush=True)
        resumes: dict[int, bytes] = {}
        # Where the time goes: the registry's CPU seconds against the burst's wall time
        # (two cores: at most 2 s of CPU a second), and the machine's other load.
        registry = psutil.Process(lab.procs[1].pid)
        for how in ("password", "resume", "password"):
            cpu0, t0, load0 = _cpu(registry), time.perf_counter(), os.getloadavg()[0]
            waits, failed = _burst(clients, how, resumes, args.derive)
            wall, cpu = time.perf_counter() - t0, _cpu(registry) - cpu0
            print(
                f"  {how:8s}: p50 {statistics.median(waits):.2f} s,"
                f" p99 {percentile(waits, 0.99):.2f} s,"
                f" max {max(waits):.2f} s, {failed} failed; registry CPU {cpu:.2f} s in"
                f" {wall:.2f} s ({cpu / n * 1e3:.0f} ms a login); load {load0:.1f}",
                flush=True,
            )
    finally:
        client_module.mailbox_key_from_password = derive
        for s in sessions:
            close_session(s)
        lab.stop()
    print(f"load average after {os.getloadavg()[0]:.2f}; logs in {lab.tmp}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
