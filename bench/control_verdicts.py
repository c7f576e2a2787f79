"""bench_control_latency's verdicts: a round's figures against the issues' targets."""

from __future__ import annotations

import numpy as np

from bench.control_rounds import Round


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.array(values) * 1000, q)) if values else float("nan")


def verdict(accepted: list[float], rtts: list[float], path_rtts: list[float]) -> str:
    """The issue's target, judged against each round trip: p50 within 2x RTT, p99 under 5 ms."""
    p50, p99 = pct(accepted, 50), pct(accepted, 99)
    ratios = ", ".join(
        f"{p50 / pct(r, 50):.1f}x the {name} RTT"
        for name, r in (("2-client", rtts), ("path", path_rtts))
    )
    ok50 = "met" if p50 <= 2 * pct(path_rtts, 50) else "missed"
    ok99 = "met" if p99 < 5.0 else "missed"
    return (
        f"target: p50 {p50:.2f} ms = {ratios} (<= 2x path RTT: {ok50}); "
        f"p99 {p99:.2f} ms (< 5 ms: {ok99})"
    )


def against_peer(ours: Round, peer: Round) -> str:
    """Issue 22's target: ours within 1.3x the plain peer's p50 and 1.5x its p99, same run.

    Judged on all commands of each loop; beside it, the median over
    neighbouring block pairs of the ratio of their p50s (a burst of other
    users' work spoils one block, not the median).
    """
    a, b = ours.accepted, peer.accepted
    r50, r99 = pct(a, 50) / pct(b, 50), pct(a, 99) / pct(b, 99)
    pairs = [
        pct(x, 50) / pct(y, 50) for x, y in zip(ours.blocks, peer.blocks, strict=False) if x and y
    ]
    paired = f"{float(np.median(pairs)):.2f}x" if pairs else "n/a"
    return (
        f"against the plain peer: p50 {pct(a, 50):.2f} / {pct(b, 50):.2f} ms = {r50:.2f}x "
        f"(<= 1.3x: {'met' if r50 <= 1.3 else 'missed'}); p99 {pct(a, 99):.2f} / "
        f"{pct(b, 99):.2f} ms = {r99:.2f}x (<= 1.5x: {'met' if r99 <= 1.5 else 'missed'}); "
        f"p50 ratio over {len(pairs)} block pairs, median: {paired}"
    )
