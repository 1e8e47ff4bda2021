"""Calibration of the intervals the product shows (issue 31, part 1).

Many simulated flights whose truth is NOT the estimator's model: each flight's true parameters are a
hidden seeded truth off the paper set (``sim.truth.true_parameters(seed)``: model error), its packs
start at a random SoC, and a motor loses a random share of its power at a random time. The
estimator (``paper_si``, the service's default) consumes the flight's noisy telemetry; at a
checkpoint after the fault it is asked what the product shows:

* the 2σ SoC and pack-temperature bands (``Estimate.soc ± 2 soc_sd``, ``pack_temp_c ± 2 pack_temp_sd``)
  — nominal 95.4 %, target 90–98 %;
* the 90 % interval (p05–p95, ``predict_from_estimator``, the one prediction path, 200 samples) of
  each pack's SoC at the end of the next ``--horizon`` seconds of the flight's actual load
  ("landing SoC"), and of the time to the vehicle's first failure (cut-off) on its actual future
  load — target 85–95 %.

The fault magnitude the prediction is given is the diagnoser's kind of estimate: the truth plus
N(0, 0.05) (the prediction draws no fault uncertainty of its own). A truth that fails before the
horizon ends has no landing SoC (not counted there).

    python benchmarks/bench_calibration.py [--flights 40] [--seed 0] [--horizon 300]

Prints one line per flight, then the figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs_pdm.estimation.estimator import StateEstimator  # noqa: E402
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator  # noqa: E402
from gcs_pdm.estimation.synthetic import fly_synthetic  # noqa: E402
from gcs_pdm.models.params import MOTOR_NAMES, builtin  # noqa: E402
from gcs_pdm.sim.truth import true_parameters  # noqa: E402


def calibration_flight(k: int, seed: int):
    """Flight ``k``: (its generator, positioned for the draws after the flight, the flight, the
    faulty motor, its true magnitude, the checkpoint s). Shared with ``bench_motor_temp_calibration``."""
    rng = np.random.default_rng([seed, k])
    truth = true_parameters(1000 + k)
    motor = MOTOR_NAMES[int(rng.integers(0, 2))]
    magnitude = float(rng.uniform(0.3, 0.75))
    fault_s = float(rng.uniform(150.0, 600.0))
    soc0 = float(rng.uniform(0.8, 1.0))
    flight = fly_synthetic(truth, rng, duration_s=4000.0, fault_motor=motor, fault_magnitude=magnitude,
                           fault_time_s=fault_s, initial_soc=soc0)
    checkpoint = fault_s + float(rng.uniform(60.0, 240.0))
    return rng, flight, motor, magnitude, checkpoint


def one_flight(k: int, seed: int, horizon_s: float, n_samples: int) -> dict | None:
    rng, flight, motor, magnitude, checkpoint = calibration_flight(k, seed)
    t_end = float(flight.time_s[-1])
    failed_at = flight.info.get("failed_at_s")
    if checkpoint > t_end - 30.0:
        return None
    est = StateEstimator(builtin("paper_si"))
    for fr in flight.frames:
        if fr.time_s > checkpoint:
            break
        est.consume(fr)
    if not est.ready():
        return None
    e = est.estimate()
    i = int(np.searchsorted(flight.time_s, checkpoint))
    true_soc, true_temp = flight.soc[i], flight.pack_temp_c[i]
    soc_in = np.abs(e.soc - true_soc) <= 2.0 * e.soc_sd
    temp_in = np.abs(e.pack_temp_c - true_temp) <= 2.0 * e.pack_temp_sd
    # the future as flown: the flight's own shaft power from the checkpoint on
    dt = np.diff(flight.time_s[i:], prepend=flight.time_s[i])
    future = FutureLoad(dt, flight.shaft_power_w[i:], flight.ambient_c[i:])
    fault = np.zeros(2)
    fault[MOTOR_NAMES.index(motor)] = float(np.clip(magnitude + rng.normal(0.0, 0.05), 0.0, 1.0))
    pred = predict_from_estimator(est, future, rng=rng, n_samples=n_samples, fault=fault, trajectories=False)
    out = {"flight": k, "checkpoint_s": round(checkpoint, 1), "soc_in": soc_in.tolist(), "temp_in": temp_in.tolist(),
           "soc_z": ((e.soc - true_soc) / np.maximum(e.soc_sd, 1e-9)).round(2).tolist(),
           "temp_z": ((e.pack_temp_c - true_temp) / np.maximum(e.pack_temp_sd, 1e-9)).round(2).tolist(),
           "temp_sd": np.round(e.pack_temp_sd, 3).tolist()}
    # time to the first failure (cut-off): known on the truth only when it failed in the profile
    if failed_at is not None:
        true_ttf = float(flight.time_s[min(failed_at[0], flight.time_s.size - 1)]) - checkpoint \
            if isinstance(failed_at, tuple) else float(failed_at) - checkpoint
        lo, hi = pred.time_to_failure_s[0], pred.time_to_failure_s[2]
        out["ttf"] = {"true_s": round(true_ttf, 1), "p05": float(lo), "p95": float(hi), "in": bool(lo <= true_ttf <= hi)}
    # landing SoC: the SoC after the next horizon_s of the flight's load, where the truth got there
    j = int(np.searchsorted(flight.time_s, checkpoint + horizon_s))
    if j < flight.time_s.size - 1:
        hz = FutureLoad(dt[:j - i + 1], flight.shaft_power_w[i:j + 1], flight.ambient_c[i:j + 1])
        p2 = predict_from_estimator(est, hz, rng=rng, n_samples=n_samples, fault=fault, trajectories=False,
                                    per_sample=True, stop_on_failure=False)
        soc_end = p2.sample_end_soc
        q = np.nanquantile(soc_end, [0.05, 0.95], axis=0)
        truth_end = flight.soc[j]
        inside = (q[0] <= truth_end) & (truth_end <= q[1])
        out["landing"] = {"in": inside.tolist(), "true": truth_end.round(4).tolist(), "p05": q[0].round(4).tolist(),
                          "p95": q[1].round(4).tolist()}
    return out


def coverage(hits: list[bool]) -> dict:
    n = len(hits)
    return {"n": n, "coverage": (sum(hits) / n) if n else None}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--horizon", type=float, default=300.0)
    ap.add_argument("--samples", type=int, default=200)
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = []
    for k in range(args.flights):
        r = one_flight(k, args.seed, args.horizon, args.samples)
        if r is None:
            print(f"flight {k}: skipped (ended before its checkpoint, or no estimate)", flush=True)
            continue
        rows.append(r)
        print(f"flight {k}: soc in 2sd {sum(r['soc_in'])}/4, temp {sum(r['temp_in'])}/4, "
              f"landing {sum(r['landing']['in']) if 'landing' in r else '-'}/4, "
              f"ttf {'in' if r.get('ttf', {}).get('in') else ('out' if 'ttf' in r else '-')}", flush=True)
    soc = [h for r in rows for h in r["soc_in"]]
    temp = [h for r in rows for h in r["temp_in"]]
    landing = [h for r in rows if "landing" in r for h in r["landing"]["in"]]
    ttf = [r["ttf"]["in"] for r in rows if "ttf" in r]
    result = {"flights": len(rows), "seed": args.seed, "horizon_s": args.horizon,
              "soc_2sd": coverage(soc), "pack_temp_2sd": coverage(temp),
              "landing_soc_90": coverage(landing), "time_to_cutoff_90": coverage(ttf),
              # the spread of (estimate - truth) / σ shown: 1 when the σ is the error's own
              "soc_z_sd": float(np.std([z for r in rows for z in r["soc_z"]])) if rows else None,
              "pack_temp_z_sd": float(np.std([z for r in rows for z in r["temp_z"]])) if rows else None,
              "targets": {"soc_2sd": [0.90, 0.98], "pack_temp_2sd": [0.90, 0.98], "landing_soc_90": [0.85, 0.95],
                          "time_to_cutoff_90": [0.85, 0.95]},
              "wall_s": time.perf_counter() - t0}
    for name in ("soc_2sd", "pack_temp_2sd", "landing_soc_90", "time_to_cutoff_90"):
        c = result[name]
        print(f"{name}: {c['coverage']:.3f} of {c['n']}" if c["coverage"] is not None else f"{name}: no cases")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
