"""Figures of the estimator's model-consistency test (docs/estimation.md, "Does the pack still
match its model?"): false alarms on the detection table's fault-free flights and on the recorded
tlogs, detection time on flights whose pack's resistance differs from the set's.

    python scripts/evaluate_model_mismatch.py [--quick]

The last line is one JSON object.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.synthetic import PackDegradation, fly_synthetic
from gcs_pdm.frames import PackFrame
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.models.params import default_set
from gcs_pdm.sim.truth import true_parameters

FLIGHTS = Path(__file__).resolve().parent.parent / "fixtures" / "flights"


def watch(est: StateEstimator):
    """A frame consumer feeding ``est`` that keeps the largest statistic and the first raise per pack."""
    worst = np.full((len(est.pack_names), 2), -np.inf)
    first = np.full(len(est.pack_names), np.nan)

    def consume(fr):
        est.consume(fr)
        if isinstance(fr, PackFrame):
            np.fmax(worst, est.packs.consistency.statistic(), out=worst)
            new = est.model_mismatch_active & np.isnan(first)
            first[new] = fr.time_s
    return consume, worst, first


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4 nominal flights instead of 10")
    args = ap.parse_args()
    t0 = time.process_time()
    out: dict = {}
    nominal = {"flights": 0, "hours": 0.0, "raises": 0, "max_statistic": 0.0}
    for k in range(4 if args.quick else 10):
        flight = fly_synthetic(true_parameters(2013 + k), np.random.default_rng(100 + k), duration_s=1200.0,
                               initial_soc=float(np.random.default_rng(k).uniform(0.85, 1.0)))
        est = StateEstimator(default_set())
        consume, worst, _ = watch(est)
        for fr in flight.frames:
            consume(fr)
        nominal["flights"] += 1
        nominal["hours"] += flight.duration_s / 3600.0
        nominal["raises"] += est.counters["model_mismatch_raised"]
        nominal["max_statistic"] = max(nominal["max_statistic"], float(np.nanmax(worst)))
    nominal["false_alarms_per_hour"] = nominal["raises"] / nominal["hours"]
    out["nominal_synthetic"] = nominal
    rec = {"flights": 0, "judged": 0, "raises": 0, "max_statistic": 0.0}
    for tlog in sorted(FLIGHTS.glob("*.tlog")):
        est = StateEstimator(default_set())
        consume, worst, _ = watch(est)
        replay_tlog(tlog, frame_consumer=consume)
        rec["flights"] += 1
        rec["raises"] += est.counters["model_mismatch_raised"]
        if np.isfinite(worst).any():
            rec["judged"] += 1
            rec["max_statistic"] = max(rec["max_statistic"], float(np.nanmax(worst[np.isfinite(worst)])))
    out["recorded_tlogs"] = rec
    detection = []
    for rise in (1.3, 1.6, 2.0):
        for seed in (300, 301):
            flight = fly_synthetic(default_set(), np.random.default_rng(seed), duration_s=900.0,
                                   degradation=(PackDegradation("LLF20", resistance=rise),))
            est = StateEstimator(default_set())
            consume, worst, first = watch(est)
            for fr in flight.frames:
                consume(fr)
            detection.append({"resistance": rise, "seed": seed, "detected_at_s": None if np.isnan(first[0]) else
                              round(float(first[0]), 1), "max_statistic": round(float(worst[0, 0]), 3),
                              "other_packs_raised": int(np.isfinite(first[1:]).sum())})
    out["resistance_mismatch_LLF20"] = detection
    est = StateEstimator(default_set())
    out["bound"] = round(est.packs.consistency.raise_at, 4)
    out["clear_below"] = round(est.packs.consistency.clear_at, 4)
    out["cpu_s"] = round(time.process_time() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
