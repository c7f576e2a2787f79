"""The twin against hidden robots: recovered parameters, open-loop error, seconds needed.

For several hidden parameter sets (each wheel's grip, wheel base, latency, IR gains and
noise: services/bridge/body_truth.py), the emulated Khepera's body drives the calibration
dance (common/controller/calibration.py) on a simulated clock, recorded as a real run is
(services/bridge/rehearse.py: the camera sees the true pose with 0.3 mm of noise at
15 Hz), and ``wart calibrate``'s fit (common/twin/fit.py) recovers what it can. Printed
per set: each recovered value's error against the truth; the 5 s open-loop position
error (median mm) of the datasheet model and of the twin on a second run of the same
robot the fit never saw (another seed: other noise); and the seconds of the dance after
which the drive's four values are within 0.5 % (scales), 0.5 mm (wheel base) and 10 ms
(latency) of the truth.

    python -m bench.bench_twin [--sets 5] [--seed 1]
"""

from __future__ import annotations

import time

import numpy as np

from bench import cli as bench_cli
from common.twin.fit import calibrate, open_loop_error, run_data
from common.twin.motion import Drive
from services.bridge.body_truth import BodyTruth
from services.bridge.rehearse import rehearse

SPANS_S = (10.0, 15.0, 20.0, 25.0, 30.0, 40.0)
TOLERANCE = {"scale_left": 0.005, "scale_right": 0.005, "wheel_base_mm": 0.5, "latency_s": 0.01}


def hidden(rng: np.random.Generator, n: int) -> BodyTruth:
    """A robot that differs from its datasheet by 2 to 8 % in grip, up to 4 mm in wheel base."""
    slip = rng.uniform(0.02, 0.08)
    left_first = rng.random() < 0.5
    scale = (1.0 - slip, 1.0 - rng.uniform(0.0, slip / 2))
    return BodyTruth(
        wheel_scale=scale if left_first else (scale[1], scale[0]),
        wheel_base_mm=float(53.0 + rng.uniform(-4.0, 4.0)),
        latency_s=float(rng.uniform(0.02, 0.12)),
        ir_gain=tuple(float(g) for g in rng.uniform(0.8, 1.2, 8)),
        ir_noise_counts=float(rng.uniform(0.0, 5.0)),
        seed=n,
    )


def truth_of(body: BodyTruth) -> dict[str, float]:
    out = {
        "scale_left": body.wheel_scale[0],
        "scale_right": body.wheel_scale[1],
        "wheel_base_mm": body.wheel_base_mm or 53.0,
        "latency_s": body.latency_s,
    }
    out.update({f"ir{i}_gain": g for i, g in enumerate(body.ir_gain)})
    return out


def seconds_needed(body: BodyTruth, seed: int) -> float | None:
    truth = truth_of(body)
    for span in SPANS_S:
        twin = calibrate("k1", [("dance", rehearse(body, seed=seed, seconds=span))])
        got = {e.name: e for e in twin.drive}
        if all(not got[k].refused and abs(got[k].value - truth[k]) <= t
               for k, t in TOLERANCE.items()):  # fmt: skip
            return span
    return None


def main() -> None:
    p = bench_cli.parser("bench_twin", __doc__)
    p.add_argument("--sets", type=int, default=5, help="hidden parameter sets (default 5)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    rng = np.random.default_rng(args.seed)
    ratios = []
    for n in range(args.sets):
        body = hidden(rng, n)
        truth = truth_of(body)
        t0 = time.perf_counter()
        rec = rehearse(body, seed=100 + n)
        twin = calibrate("k1", [("dance", rec)])
        fit_s = time.perf_counter() - t0
        got = {e.name: e for e in (*twin.drive, *twin.proximity)}
        errors = []
        for name in ("scale_left", "scale_right", "wheel_base_mm", "latency_s"):
            e = got[name]
            err = "refused" if e.refused else f"{e.value - truth[name]:+.4f}"
            errors.append(f"{name} {truth[name]:.4g} {err}")
        gains = [abs(got[f"ir{i}_gain"].value - truth[f"ir{i}_gain"]) for i in range(8)
                 if not got[f"ir{i}_gain"].refused]  # fmt: skip
        other = run_data(rehearse(body, seed=200 + n), "other")
        datasheet = open_loop_error(Drive(), other, 5.0)
        fitted = open_loop_error(twin.fitted_drive(), other, 5.0)
        ratios.append(fitted / datasheet)
        needed = seconds_needed(body, 100 + n)
        print(
            f"set {n}: " + "; ".join(errors)
            + f"; IR gains within {max(gains):.3f} ({len(gains)} of 8 fitted)"
            + f"; 5 s open-loop on another run: datasheet {datasheet:.1f} mm, twin {fitted:.1f}"
            + f" mm ({fitted / datasheet:.2f}); the drive within tolerance after "
            + (f"{needed:g} s" if needed else f"more than {SPANS_S[-1]:g} s")
            + f"; rehearsal and fit {fit_s:.1f} s",
            flush=True,
        )  # fmt: skip
    print(f"twin / datasheet 5 s error: worst {max(ratios):.3f}, median {np.median(ratios):.3f}")


if __name__ == "__main__":
    main()
