"""bench_viewer_sessions' class as seen from the viewer's process: the child processes.

Child starts ``python -m bench.bench_viewer_sessions --as-clients|--as-browsers``
and relays its PROGRESS, READY and RESULT lines; _class_children starts the
class (sessions dealt round the viewers), _merge joins the headless
children's results, _print_sessions prints what the class received.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO, Any

from bench.viewer_clients import _stats

USERS = [("ana", "ana-pw"), ("ben", "ben-pw")]
ARENA = "arena"


# -- the viewer (this process) ---------------------------------------------------------------


class Child:
    """A child process whose PROGRESS lines are relayed and whose RESULT is kept."""

    def __init__(self, name: str, args: list[str]) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = str(Path(__file__).resolve().parent.parent)
        self.name = name
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.bench_viewer_sessions", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        self.ready = threading.Event()
        self.result: dict[str, Any] | None = None
        self.tail: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        out: IO[str] | None = self.proc.stdout
        assert out is not None
        for line in out:
            line = line.rstrip()
            self.tail = [*self.tail[-30:], line]
            if line.startswith("PROGRESS "):
                print(f"  [{self.name}] {line[9:]}", flush=True)
            elif line == "READY":
                self.ready.set()
            elif line.startswith("RESULT "):
                self.result = json.loads(line[7:])
        self.ready.set()  # ended: nobody waits for ever

    def go(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("GO\n")
        self.proc.stdin.flush()

    def finish(self, timeout: float) -> dict[str, Any]:
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        if self.result is None:
            raise RuntimeError(f"{self.name} gave no result:\n" + "\n".join(self.tail))
        return self.result

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)


def _class_children(
    args: argparse.Namespace,
    ws_urls: list[str],
    http_url: str,
    users: list[tuple[str, str]],
    address: str,
    arena: str,
) -> list[Child]:
    """The class: headless clients (one process per viewer, sessions dealt round the
    viewers) and the Chromium pages (on the first viewer)."""
    common = [
        "--seconds",
        str(args.seconds),
        "--users-json",
        json.dumps(users),
        "--address",
        address,
        "--arena",
        arena,
    ]
    children: list[Child] = []
    per_viewer = [len(range(i, args.sessions, len(ws_urls))) for i in range(len(ws_urls))]
    slow_left = args.slow
    for i, (url, sessions) in enumerate(zip(ws_urls, per_viewer, strict=True)):
        slow = min(slow_left, sessions)
        slow_left -= slow
        children.append(
            Child(
                f"headless-{i}" if len(ws_urls) > 1 else "headless",
                [
                    "--as-clients",
                    url,
                    "--sessions",
                    str(sessions),
                    "--slow",
                    str(slow),
                    "--slow-every",
                    str(args.slow_every),
                    *common,
                ],
            )
        )
    if args.browsers:
        children.append(
            Child(
                "chromium", ["--as-browsers", http_url, "--browsers", str(args.browsers), *common]
            )
        )
    return children


def _merge(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The headless children's results as one class (means weighted by sessions)."""

    def merged(key: str) -> dict[str, float]:
        parts = [(r[key], r["sessions"] if key != "slow_frames" else r["slow"]) for r in results]
        parts = [(st, n) for st, n in parts if n]
        if not parts:
            return _stats([])
        total = sum(n for _, n in parts)
        return {
            "min": min(st["min"] for st, _ in parts),
            "mean": sum(st["mean"] * n for st, n in parts) / total,
            "max": max(st["max"] for st, _ in parts),
        }

    return {
        "frames": merged("frames"),
        "slow_frames": merged("slow_frames"),
        "mb": merged("mb"),
        "client_cpu": sum(r["client_cpu"] for r in results),
        "errors": [e for r in results for e in r["errors"]][:5],
        "failed": [f for r in results for f in r.get("failed", [])],
        "retried": [f for r in results for f in r.get("retried", [])],
    }


def _print_sessions(
    args: argparse.Namespace, head: dict[str, Any], results: dict[str, dict[str, Any]]
) -> None:
    """What the class received: headless sessions, slow readers, Chromium pages, bytes."""
    f, mb = head["frames"], head["mb"]
    print(
        f"  headless updates/s per session: min {f['min']:.1f} mean {f['mean']:.1f} "
        f"max {f['max']:.1f}"
    )
    if args.slow:
        s = head["slow_frames"]
        print(
            f"  slow readers ({args.slow}, reading every {args.slow_every} s): "
            f"min {s['min']:.1f} mean {s['mean']:.1f} max {s['max']:.1f} updates/s"
        )
    if "chromium" in results:
        cf, cm = results["chromium"]["frames"], results["chromium"]["mb"]
        paint = results["chromium"]["paint_fps"]
        print(
            f"  Chromium updates/s per page: min {cf['min']:.1f} mean {cf['mean']:.1f} "
            f"max {cf['max']:.1f}; {cm['mean']:.3f} MB/s per page; the page painted "
            f"{paint['min']:.1f} to {paint['max']:.1f} animation frames/s"
        )
    print(f"  bytes per session: {mb['mean']:.3f} MB/s (min {mb['min']:.3f}, max {mb['max']:.3f})")
