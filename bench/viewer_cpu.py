"""bench_viewer_sessions' CPU accounting: this process's threads, or named processes."""

from __future__ import annotations

import threading
import time

import psutil


def _thread_cpu() -> dict[str, float]:
    """CPU seconds so far of each of this process's threads, by thread name."""

    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for t in psutil.Process().threads():
        name = names.get(t.id, "other")
        out[name] = out.get(name, 0.0) + t.user_time + t.system_time
    return out


def _cpu_over(seconds: float) -> tuple[float, dict[str, float]]:
    """This process's CPU time over ``seconds`` of wall time, as a share of one core
    (and each thread's share, the busiest first)."""
    c0, t0, th0 = time.process_time(), time.monotonic(), _thread_cpu()
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    th1 = _thread_cpu()
    threads = {n: (v - th0.get(n, 0.0)) / elapsed for n, v in th1.items()}
    top = dict(sorted(threads.items(), key=lambda kv: -kv[1])[:4])
    return (time.process_time() - c0) / elapsed, top


def _proc_cpu(pids: dict[str, int], seconds: float) -> dict[str, float]:
    """Each named process's CPU over ``seconds`` of wall time, as a share of one core."""

    procs = {name: psutil.Process(pid) for name, pid in pids.items()}
    t0 = time.monotonic()
    c0 = {n: sum(p.cpu_times()[:2]) for n, p in procs.items()}
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    return {n: (sum(p.cpu_times()[:2]) - c0[n]) / elapsed for n, p in procs.items()}
