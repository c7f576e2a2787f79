"""bench_control_latency's measuring rounds: our loop alone, or in blocks against the plain peer.

Each round runs both RTT probes beside the engine's accepted/applied
latencies and notes the CPU each role's processes used per tick.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

from bench.control_probes import path_probe, rtt_probe
from bench.control_timing import TimedEngine
from bench.plain_peer import PlainEngine
from common.zconfig import NetworkOptions


def cpu_seconds(pids: list[int]) -> float:
    """User + system CPU time the processes used so far (Linux /proc); nan elsewhere."""
    total = 0.0
    try:
        for pid in pids:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")
    return total


class Round(NamedTuple):
    rtts: list[float]  # two sessions in the world's process
    path_rtts: list[float]  # world's session <-> controllers' process (path_probe)
    accepted: list[float]
    applied: list[float]
    cpu_ms_per_tick: dict[str, float]  # role -> CPU ms its processes used per 20 ms tick
    blocks: tuple[list[float], ...] = ()  # accepted, block by block (alternating with the peer)


def measure(
    engine: TimedEngine,
    z: Any,
    options: NetworkOptions,
    seconds: float,
    pids: dict[str, list[int]],
) -> Round:
    """One round: both RTT probes beside the engine's accepted/applied latencies, CPU per role."""
    rtts: list[float] = []
    path_rtts: list[float] = []
    stop = threading.Event()
    engine.accepted, engine.applied = [], []
    probes = [
        threading.Thread(target=rtt_probe, args=(options, stop, rtts)),
        threading.Thread(target=path_probe, args=(z, stop, path_rtts)),
    ]
    for probe in probes:
        probe.start()
    engine.recording = True
    before = {role: cpu_seconds(p) for role, p in pids.items()}
    start = time.monotonic()
    try:
        time.sleep(seconds)
    finally:
        ticks = (time.monotonic() - start) / engine.settings.tick_s
        cpu = {role: (cpu_seconds(p) - before[role]) * 1000 / ticks for role, p in pids.items()}
        engine.recording = False
        stop.set()
        for probe in probes:
            probe.join(10)
    return Round(rtts, path_rtts, list(engine.accepted), list(engine.applied), cpu)


class _ByBlock:
    """A probe's round trips, filed under the block (ours or the peer's) running when measured."""

    def __init__(self, current: list[str], into: dict[str, list[float]]) -> None:
        self.current, self.into = current, into

    def append(self, value: float, /) -> None:
        self.into[self.current[0]].append(value)


def measure_against_peer(
    engine: TimedEngine,
    peer: PlainEngine,
    z: Any,
    options: NetworkOptions,
    seconds: float,
    block: float,
    pids: dict[str, list[int]],
) -> dict[str, Round]:
    """Ours (MAC) and the plain peer in alternating blocks of ``block`` seconds, ``seconds`` each.

    Only one loop puts samples at a time; both engines keep stepping and
    building samples, so the machine carries the same work in both blocks
    and slow drifts of its load (other users) fall on both alike; short
    blocks spread the other users' bursts over both. The first 0.1 s of each
    block is not recorded: commands answering the other loop's last samples
    are still arriving then.
    """
    kinds = ("mac", "peer")
    current = [kinds[0]]
    rtts: dict[str, list[float]] = {k: [] for k in kinds}
    path_rtts: dict[str, list[float]] = {k: [] for k in kinds}
    cpu = {k: dict.fromkeys(pids, 0.0) for k in kinds}
    blocks: dict[str, list[list[float]]] = {k: [] for k in kinds}
    ticks = dict.fromkeys(kinds, 0.0)
    stop = threading.Event()
    engine.accepted, engine.applied = [], []
    peer.accepted, peer.applied = [], []
    probes = [
        threading.Thread(target=rtt_probe, args=(options, stop, _ByBlock(current, rtts))),
        threading.Thread(target=path_probe, args=(z, stop, _ByBlock(current, path_rtts))),
    ]
    for probe in probes:
        probe.start()
    try:
        # Two blocks unrecorded first: each loop's first samples after a pause find
        # cold caches and sleeping threads on both ends.
        for i in range(-2, 2 * max(1, round(seconds / block))):
            kind = kinds[i % 2]
            engine.recording = peer.recording = False
            ours = kind == "mac"
            (peer.publishing if ours else engine.publishing).clear()
            (engine.publishing if ours else peer.publishing).set()
            time.sleep(0.1)
            if i < 0:
                time.sleep(block)
                continue
            current[0] = kind
            engine.recording = peer.recording = True
            before = {role: cpu_seconds(p) for role, p in pids.items()}
            start = time.monotonic()
            first = len(engine.accepted if ours else peer.accepted)
            time.sleep(block)
            blocks[kind].append((engine.accepted if ours else peer.accepted)[first:])
            ticks[kind] += (time.monotonic() - start) / engine.settings.tick_s
            for role, p in pids.items():
                cpu[kind][role] += cpu_seconds(p) - before[role]
    finally:
        engine.recording = peer.recording = False
        engine.publishing.set()
        peer.publishing.clear()
        stop.set()
        for probe in probes:
            probe.join(10)
    lists = {"mac": (engine.accepted, engine.applied), "peer": (peer.accepted, peer.applied)}
    return {
        k: Round(
            rtts[k],
            path_rtts[k],
            list(lists[k][0]),
            list(lists[k][1]),
            {role: ms * 1000 / max(ticks[k], 1.0) for role, ms in cpu[k].items()},
            tuple(blocks[k]),
        )
        for k in kinds
    }
