"""Login round trip against a real registry (password with argon2id, and identity key),
then a class logging in at once: 50 and 100 concurrent clients, all at the same
instant and spread over 10 s, with p50 / p99 per client.

.venv/bin/python -m bench.login_rtt [N]
"""

from __future__ import annotations

import functools
import statistics
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import nacl.pwhash
import zenoh

from bench import cli as bench_cli
from bench.labproc import BenchLab
from common.auth import create_identity_key
from common.client import lab_client as client_module
from common.client.lab_client import LabClient
from common.service import close_session, open_session
from services.registry.accounts_db import MEMLIMIT, OPSLIMIT, RegistryDB

PASSWORD = "benchmark password"


def argon2id_cost(n: int = 10) -> float:
    """Seconds of one argon2id check at the registry's parameters, on this machine."""

    stored = nacl.pwhash.argon2id.str(b"x" * 12, opslimit=OPSLIMIT, memlimit=MEMLIMIT)
    t0 = time.perf_counter()
    for _ in range(n):
        nacl.pwhash.verify(stored, b"x" * 12)
    return (time.perf_counter() - t0) / n


def class_at_once(
    lab: BenchLab, sessions: list[zenoh.Session], clients: int, spread_s: float
) -> list[float]:
    """``clients`` students on up to 20 Zenoh sessions log in; each one's wait (s)."""
    start = threading.Barrier(clients)

    def one(i: int) -> float:
        client = LabClient(
            sessions[i % len(sessions)],
            lab.realm,
            lab.identity.verify_key,
            presence=False,
            via=f"student-{i}",
        )
        start.wait()
        time.sleep(spread_s * i / clients)
        t0 = time.perf_counter()
        client.login("alice", PASSWORD)
        took = time.perf_counter() - t0
        client.close()
        return took

    with ThreadPoolExecutor(clients) as pool:
        return sorted(pool.map(one, range(clients)))


def main() -> None:
    p = bench_cli.parser("login_rtt", __doc__)
    p.add_argument("n", type=int, nargs="?", default=30, help="logins of each kind (default 30)")
    n = p.parse_args().n
    lab = BenchLab(["alice"], PASSWORD)
    key = create_identity_key(lab.tmp / "script.key")
    db = RegistryDB(lab.tmp / "registry.db")
    db.add_user("script", ["service"], public_key=bytes(key.verify_key))
    db.close()
    lab.start()
    session = open_session(lab.options, wait=10.0)
    try:
        client = LabClient(session, lab.realm, lab.identity.verify_key, presence=False)
        for what, login in (
            ("password", lambda: client.login("alice", PASSWORD)),
            ("ed25519 key", lambda: client.login_with_key("script", key)),
        ):
            login()
            times = []
            for _ in range(n):
                t0 = time.perf_counter()
                login()
                times.append(time.perf_counter() - t0)
            times.sort()
            print(
                f"login ({what}): median {statistics.median(times) * 1e3:.1f} ms, "
                f"p90 {times[int(len(times) * 0.9)] * 1e3:.1f} ms over {n}"
            )
        cost = argon2id_cost()
        print(f"argon2id check (registry parameters): {cost * 1e3:.1f} ms of one core")
        # A client derives its mailbox key from the password (argon2id too) before it
        # asks: on a student's own machine that costs the lab nothing, but here the
        # clients share this machine's two cores with the registry. Both are shown.
        # Sessions opened (and seen by the registry) before the clock starts.
        sessions = [open_session(lab.options, wait=10.0) for _ in range(20)]
        for s in sessions:
            LabClient(s, lab.realm, lab.identity.verify_key, presence=False).login_with_key(
                "script", key
            )
        derive = client_module.mailbox_key_from_password
        for where, kdf in (
            ("clients' key derivation on this machine too", derive),
            ("clients' key derivation on their own machines", functools.cache(derive)),
        ):
            client_module.mailbox_key_from_password = kdf
            kdf("bench", "alice", PASSWORD)
            print(f"-- {where}")
            for clients, spread in ((1, 0.0), (50, 0.0), (100, 0.0), (100, 10.0)):
                waits = class_at_once(lab, sessions, clients, spread)
                p99 = waits[min(len(waits) - 1, int(len(waits) * 0.99))]
                how = "at the same instant" if spread == 0 else f"spread over {spread:.0f} s"
                print(
                    f"{clients:3d} concurrent logins {how}: p50 {statistics.median(waits):.2f} s,"
                    f" p99 {p99:.2f} s, max {waits[-1]:.2f} s",
                    flush=True,
                )
        client_module.mailbox_key_from_password = derive
        for s in sessions:
            close_session(s)
        t0 = time.perf_counter()
        for _ in range(200):
            client.directory()
        print(f"directory query: {(time.perf_counter() - t0) / 200 * 1e3:.2f} ms per round trip")
    finally:
        close_session(session)
        lab.stop()


if __name__ == "__main__":
    main()
