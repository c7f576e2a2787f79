"""Chat throughput through one room: M members, S senders, every line to every member.

    .venv/bin/python -m bench.chat_throughput [MEMBERS] [LINES_PER_SENDER] [SENDERS]

Members are LabClients in this process, spread over several Zenoh sessions;
they verify every event (the room seals each one) as a real client does.
"""

from __future__ import annotations

import functools
import threading
import time

from bench import cli as bench_cli
from bench.labproc import BenchLab
from common.client.lab_client import LabClient
from common.messages import RoomEvent
from common.service import close_session, open_session

PASSWORD = "benchmark password"


def main() -> None:
    p = bench_cli.parser("chat_throughput", __doc__)
    p.add_argument("members", type=int, nargs="?", default=50, help="room members (default 50)")
    p.add_argument("per_sender", type=int, nargs="?", default=200, help="lines each (default 200)")
    p.add_argument("senders", type=int, nargs="?", default=5, help="members who send (default 5)")
    args = p.parse_args()
    members, per_sender, senders = args.members, args.per_sender, args.senders
    names = [f"u{i:02d}" for i in range(members)]
    lab = BenchLab(names, PASSWORD)
    lab.start(["--rate", "100000", "--burst", "100000", "--history", "100"])
    sessions = [open_session(lab.options, wait=10.0) for _ in range(max(1, members // 10))]
    total = per_sender * senders
    received: dict[str, list[int]] = {name: [] for name in names}
    done = threading.Event()
    lock = threading.Lock()
    complete = [0]
    last_at = [0.0]

    def on_event(name: str, event: RoomEvent) -> None:
        if event.line is None:
            return
        got = received[name]
        got.append(event.line.seq)
        if len(got) == total:
            with lock:
                complete[0] += 1
                last_at[0] = time.perf_counter()
                if complete[0] == members:
                    done.set()

    clients = []
    try:
        for i, name in enumerate(names):
            client = LabClient(sessions[i % len(sessions)], lab.realm, lab.identity.verify_key)
            client.login(name, PASSWORD)
            client.join("room", functools.partial(on_event, name), history=0)
            clients.append(client)
        print(f"{members} members joined; {senders} senders x {per_sender} lines")
        t0 = time.perf_counter()

        def send(client: LabClient) -> None:
            for k in range(per_sender):
                client.say("room", f"line {k} from {client.user}", wait=False)

        threads = [threading.Thread(target=send, args=(c,)) for c in clients[:senders]]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        sent_in = time.perf_counter() - t0
        ok = done.wait(120.0)
        elapsed = (last_at[0] if ok else time.perf_counter()) - t0
        counts = [len(v) for v in received.values()]
        lost = sum(total - c for c in counts)
        ordered = all(v == sorted(v) for v in received.values())
        print(f"sent {total} lines in {sent_in:.2f} s")
        print(
            f"every member had every line after {elapsed:.2f} s: "
            f"{total / elapsed:,.0f} lines/s through the room, "
            f"{total * members / elapsed:,.0f} deliveries/s; lost {lost}; in order: {ordered}"
        )
    finally:
        for client in clients:
            client.session = None  # skip per-client logout traffic at teardown
            client.close()
        for s in sessions:
            close_session(s)
        lab.stop()


if __name__ == "__main__":
    main()
