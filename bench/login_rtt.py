"""Login round trip against a real registry (password with argon2id, and identity key).

.venv/bin/python bench/login_rtt.py [N]
"""

from __future__ import annotations

import statistics
import sys
import time

from bench.labproc import BenchLab
from common.auth import create_identity_key
from common.client import LabClient
from common.service import close_session, open_session
from services.registry.accounts_db import RegistryDB

PASSWORD = "benchmark password"


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 30
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
        t0 = time.perf_counter()
        for _ in range(200):
            client.directory()
        print(f"directory query: {(time.perf_counter() - t0) / 200 * 1e3:.2f} ms per round trip")
    finally:
        close_session(session)
        lab.stop()


if __name__ == "__main__":
    main()
