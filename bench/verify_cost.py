"""Cost of Verifier.open per authenticated message (signature, freshness, replay, decode).

.venv/bin/python -m bench.verify_cost [N]
"""

from __future__ import annotations

import time

from bench import cli as bench_cli
from common import keys
from common.auth import RegistryIdentity, Verifier, issue_session
from common.messages import ChatSay

KEY = keys.ctx_in("lab", "lobby")


def main() -> None:
    p = bench_cli.parser("verify_cost", __doc__)
    p.add_argument("n", type=int, nargs="?", default=20_000, help="messages (default 20000)")
    n = p.parse_args().n
    identity = RegistryIdentity.generate()
    session = issue_session(identity, "lab", "alice", ["chat"])
    payloads = [
        session.seal(KEY, ChatSay(text="hello there, a typical chat line")) for _ in range(n)
    ]
    t0 = time.perf_counter()
    for _ in range(1000):
        session.seal(KEY, ChatSay(text="x"))
    seal_us = (time.perf_counter() - t0) / 1000 * 1e6
    verifier = Verifier(identity.verify_key, "lab")
    verifier.open(KEY, payloads[0], ChatSay)  # first sight of a token: its signature is checked
    t0 = time.perf_counter()
    for payload in payloads[1:]:
        verifier.open(KEY, payload, ChatSay)
    per = (time.perf_counter() - t0) / (n - 1)
    print(f"Session.seal: {seal_us:.1f} µs per message")
    print(f"Verifier.open: {per * 1e6:.1f} µs per message ({1 / per:,.0f} messages/s on one core)")
    print(f"envelope size: {len(payloads[0])} bytes for a 32-character line")


if __name__ == "__main__":
    main()
