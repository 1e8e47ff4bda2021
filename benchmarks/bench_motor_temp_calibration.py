"""Calibration of the motor temperature ± 2σ the product shows (docs/intervals.md; issue 29 item 4).

The flights are ``bench_calibration``'s (same seeds: truth off the estimator's set, a motor losing
30-75 % of its power, packs starting at SoC 0.8-1.0). The estimator (``paper_si``, the service's
default) reads each flight's noisy telemetry in two cases:

* ``esc_temperature``: the ESCs report current, rpm and temperature (the frames as flown);
* ``model_only``: the description says the ESCs report no temperature and the frames carry none,
  so the motor temperature comes from the thermal model alone, driven by the reported current
  (``StateEstimator._modelled_spread`` widens its σ).

Scored: ``Estimate.motor_temp_c ± 2 motor_temp_sd`` (``/status.motors.<m>.temperature_c``,
``temperature_sd``) against the simulated truth, at the flight's checkpoint (60-240 s after the
fault, as in ``bench_calibration``) and every ``--every`` s of the flight from 120 s to ``--until`` s. Nominal
95.4 %, target 90-98 %; the median band width (4σ) and the z spread ((estimate - truth) / σ: 1 when
the σ is the error's own) per case.

    python benchmarks/bench_motor_temp_calibration.py [--flights 40] [--seed 0] [--every 120] [--until 1200]
        [--sensor-sigma 0.5 --process-sigma 0.05]   (the motor filter's noise settings, for experiments)

Prints one line per flight, then the figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_calibration import calibration_flight  # noqa: E402
from gcs_pdm.estimation.estimator import EstimatorConfig, StateEstimator  # noqa: E402
from gcs_pdm.estimation.motor_filter import MotorFilterConfig  # noqa: E402
from gcs_pdm.frames import MotorFrame  # noqa: E402
from gcs_pdm.models.params import builtin  # noqa: E402
from gcs_pdm.vehicle.description import from_dict  # noqa: E402
from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS  # noqa: E402

CASES = ("esc_temperature", "model_only")
NOMINAL_2SD = 0.954
TARGET = (0.90, 0.98)


def without_motor_temperature_sensor(desc):
    """``desc`` with every motor's ESC described as reporting no temperature."""
    d = desc.to_dict()
    for m in d["motors"]:
        m.setdefault("readings", {})["temperature"] = False
    return from_dict(d)


def estimators(motor: MotorFilterConfig) -> dict[str, StateEstimator]:
    params = builtin("paper_si")
    vehicle = PRESETS[DEFAULT_PRESET]
    config = EstimatorConfig(motor=motor)
    return {"esc_temperature": StateEstimator(params, config, vehicle=vehicle),
            "model_only": StateEstimator(params, config, vehicle=without_motor_temperature_sensor(vehicle))}


def case_frame(case: str, frame):
    if case == "model_only" and isinstance(frame, MotorFrame):
        return dataclasses.replace(frame, temperature_c=None)
    return frame


def score(est: StateEstimator, truth_c: np.ndarray) -> list[dict]:
    e = est.estimate(details=False)
    return [{"in": bool(abs(e.motor_temp_c[q] - truth_c[q]) <= 2.0 * e.motor_temp_sd[q]),
             "z": float((e.motor_temp_c[q] - truth_c[q]) / max(float(e.motor_temp_sd[q]), 1e-9)),
             "width_c": float(4.0 * e.motor_temp_sd[q]), "error_c": float(e.motor_temp_c[q] - truth_c[q]),
             "rise_c": float(truth_c[q] - e.ambient_c)}
            for q in range(truth_c.size) if np.isfinite(e.motor_temp_c[q]) and np.isfinite(e.motor_temp_sd[q])]


def one_flight(k: int, seed: int, every_s: float, until_s: float, motor: MotorFilterConfig) -> dict | None:
    _, flight, _, _, checkpoint = calibration_flight(k, seed)
    t_end = float(flight.time_s[-1])
    if checkpoint > t_end - 30.0:
        return None
    ests = estimators(motor)
    # the estimator's cost is per frame: the through-flight samples stop at until_s
    last = min(t_end - 1.0, max(until_s, checkpoint + 1.0))
    times = sorted(set(np.arange(120.0, last, every_s).tolist()) | {checkpoint})
    out = {c: {"checkpoint": [], "through": []} for c in CASES}
    nxt = 0
    for fr in flight.frames:
        while nxt < len(times) and fr.time_s > times[nxt]:
            i = min(int(np.searchsorted(flight.time_s, times[nxt])), flight.time_s.size - 1)
            for c, est in ests.items():
                if est.ready():
                    s = score(est, flight.motor_temp_c[i])
                    out[c]["checkpoint" if times[nxt] == checkpoint else "through"] += s
            nxt += 1
        if nxt >= len(times):
            break
        for c, est in ests.items():
            est.consume(case_frame(c, fr))
    return out


def summary(samples: list[dict]) -> dict:
    if not samples:
        return {"n": 0, "coverage": None}
    z = np.array([s["z"] for s in samples])
    err = np.array([s["error_c"] for s in samples])
    return {"n": len(samples), "coverage": float(np.mean([s["in"] for s in samples])),
            "median_width_c": float(np.median([s["width_c"] for s in samples])),
            "z_sd": float(np.std(z)), "z_mean": float(np.mean(z)),
            "error_abs_p95_c": float(np.quantile(np.abs(err), 0.95)),
            "median_rise_c": float(np.median([s["rise_c"] for s in samples]))}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=float, default=120.0)
    ap.add_argument("--until", type=float, default=1200.0, help="last through-flight sample, s of flight")
    # experiments on the motor filter's noise settings (defaults: the product's MotorFilterConfig)
    ap.add_argument("--sensor-sigma", type=float, default=MotorFilterConfig.temperature_sigma_c)
    ap.add_argument("--process-sigma", type=float, default=MotorFilterConfig.process_sigma_c)
    args = ap.parse_args()
    motor = MotorFilterConfig(temperature_sigma_c=args.sensor_sigma, process_sigma_c=args.process_sigma)
    t0 = time.perf_counter()
    pooled = {c: {"checkpoint": [], "through": []} for c in CASES}
    n = 0
    for k in range(args.flights):
        r = one_flight(k, args.seed, args.every, args.until, motor)
        if r is None:
            print(f"flight {k}: skipped (ended before its checkpoint)", flush=True)
            continue
        n += 1
        for c in CASES:
            for where in ("checkpoint", "through"):
                pooled[c][where] += r[c][where]
        print(f"flight {k}: " + ", ".join(
            f"{c} {sum(s['in'] for s in r[c]['checkpoint'])}/{len(r[c]['checkpoint'])} at checkpoint, "
            f"{sum(s['in'] for s in r[c]['through'])}/{len(r[c]['through'])} through" for c in CASES), flush=True)
    result = {"flights": n, "seed": args.seed, "every_s": args.every, "until_s": args.until,
              "motor_filter": {"temperature_sigma_c": motor.temperature_sigma_c,
                               "process_sigma_c": motor.process_sigma_c}, "nominal_2sd": NOMINAL_2SD,
              "target": list(TARGET),
              **{c: {where: summary(pooled[c][where]) for where in ("checkpoint", "through")} for c in CASES},
              "wall_s": time.perf_counter() - t0}
    for c in CASES:
        for where in ("checkpoint", "through"):
            s = result[c][where]
            print(f"{c} {where}: " + (f"{s['coverage']:.3f} of {s['n']}, median band {s['median_width_c']:.2f} °C, "
                                      f"z sd {s['z_sd']:.2f}" if s["n"] else "no cases"))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
