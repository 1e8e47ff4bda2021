"""A fitted pack's set as a prior (issue 29, ``estimation.fitted_prior``): when the watch takes over,
and whether it ever does where it must not.

Prints one line per case and, last, ONE JSON object:

- ``fixtures``: every ``fixtures/flights/*.tlog`` through the paper aircraft's estimator: per flight
  the takeovers (must be none: the fixtures' hidden truth is within ±15 % of the set) and, over its
  packs, the largest |z| of each statistic the watch judges (resistance, capacity, SoC) and of the
  set's windowed innovations over their bound;
- ``off_prior``: edge540 with its pack off the set (``bench_soc_calibration.SIM_CASES``): when the
  set was contradicted, by what, and the SoC error after 120 s of flight and the 2σ share;
- ``set_on_curved_cells``: the paper set flown on cells of the extended (curved) OCV
  (``tests/test_estimation_extended.py``'s flight, 1200 s, truth 0.95 -> 0.42): per pack when the set
  and then its curve were contradicted, the largest SoC error after the takeover and after the
  curve's judgement, the 2σ share after the takeover, and the last SoC ± σ against the truth;
- ``cpu_us_per_pack_frame``: ``StateEstimator.consume`` CPU per pack frame of learn_01, with the
  watch and without (``EstimatorConfig.fitted_set_as_prior``), best of 3.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_fitted_pack_prior.py`` (≈ 2-3 min).
"""
from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import numpy as np

from bench_soc_calibration import SIM_CASES
from gcs_pdm.estimation.estimator import EstimatorConfig, StateEstimator
from gcs_pdm.frames import PackFrame
from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.replay.calibration_eval import PackTrack, simulated_case

ROOT = Path(__file__).resolve().parents[1]


def _fixtures() -> list[dict]:
    out = []
    for path in sorted((ROOT / "fixtures" / "flights").glob("*.tlog")):
        est = StateEstimator()
        worst = np.zeros(4)

        def consume(frame):
            est.consume(frame)
            b = est._pack_index.get(frame.pack) if isinstance(frame, PackFrame) else None
            watch = est.fitted_watch[b] if b is not None else None
            if watch is not None and watch.calibrator.initialised and watch.calibrator.voltage_trusted:
                window = est.packs.consistency
                z = [*watch.statistics(*est.paper_soc(b)), float(window.statistic()[b, 0]) / window.raise_at]
                np.fmax(worst, np.abs(z), out=worst)

        replay_tlog(path, mapper=FrameMapper(), frame_consumer=consume)
        row = {"flight": path.stem, "takeovers": sum(math.isfinite(w.contradicted_at_s) for w in est.fitted_watch),
               "max_abs_z": dict(zip(("resistance", "capacity", "soc", "innovations_over_bound"),
                                     np.round(worst, 2).tolist()))}
        out.append(row)
        print(f"{row['flight']}: takeovers {row['takeovers']}, largest {row['max_abs_z']}", flush=True)
    return out


def _off_prior() -> list[dict]:
    out = []
    for cap, res, start, seed in SIM_CASES:
        case = simulated_case("edge540", capacity_scale=cap, resistance_scale=res, start_soc=start, seed=seed)
        samples = []
        for k in range(case.end):
            case.feed(k)
            e = case.estimator.estimate(details=False)
            samples.append(((k + 1) * case.dt, e.soc[0], e.soc_sd[0], case.truth_run.soc[0, k]))
        s = PackTrack("edge540", *(np.array(c, dtype=float) for c in zip(*samples))).summary(150.0)
        watch = case.estimator.fitted_watch[0]
        row = {"capacity_scale": cap, "resistance_scale": res, "start_soc": start,
               "contradicted_at_s": None if math.isnan(watch.contradicted_at_s) else watch.contradicted_at_s,
               "reason": watch.reason, "max_abs_error_after_120s": s["max_abs_error"], "within_2sd": s["within_2sd"],
               "met": bool(s["max_abs_error"] <= 0.05 and s["within_2sd"] >= 0.9)}
        out.append(row)
        print(f"C x{cap} R x{res} from {start}: taken over at {row['contradicted_at_s']} s, error "
              f"{row['max_abs_error_after_120s']}, 2σ {row['within_2sd']}", flush=True)
    return out


def _set_on_curved_cells() -> dict:
    import sys
    sys.path.insert(0, str(ROOT / "tests"))  # the flight is the test's: one definition of it
    from test_estimation_extended import extended_set, fly_extended

    from gcs_pdm.models.params import PACK_NAMES, default_set

    frames, run = fly_extended(extended_set())
    est = StateEstimator(default_set())
    samples = []
    for f in frames:
        est.consume(f)
        if f.pack == PACK_NAMES[-1]:  # every pack has had this second's frame
            e = est.estimate(details=False)
            samples.append((f.time_s, e.soc, e.soc_sd))
    t = np.array([s[0] for s in samples])
    soc, sd = np.array([s[1] for s in samples]), np.array([s[2] for s in samples])
    err = np.abs(soc - run.soc.T[np.round(t).astype(int)])
    out = {}
    for b, name in enumerate(PACK_NAMES):
        w = est.fitted_watch[b]
        after, judged = t > w.contradicted_at_s, t > w.curve_contradicted_at_s
        out[name] = {"contradicted_at_s": None if math.isnan(w.contradicted_at_s) else w.contradicted_at_s,
                     "curve_contradicted_at_s": (None if math.isnan(w.curve_contradicted_at_s)
                                                 else w.curve_contradicted_at_s),
                     "max_error_after_takeover": round(float(err[after, b].max()), 3) if after.any() else None,
                     "max_error_after_curve_judged": round(float(err[judged, b].max()), 3) if judged.any() else None,
                     "within_2sd_after_takeover": (round(float(np.mean(err[after, b] <= 2 * sd[after, b])), 3)
                                                   if after.any() else None),
                     "last": {"soc": round(float(soc[-1, b]), 3), "soc_sd": round(float(sd[-1, b]), 3),
                              "truth": round(float(run.soc[b, -1]), 3)}}
        print(f"set on curved cells, {name}: {out[name]}", flush=True)
    return out


def _cpu_per_pack_frame() -> dict:
    frames = []
    replay_tlog(ROOT / "fixtures" / "flights" / "learn_01.tlog", mapper=FrameMapper(), frame_consumer=frames.append)
    n_pack = sum(isinstance(f, PackFrame) for f in frames)
    out = {}
    for label, on in (("with_watch", True), ("without_watch", False)):
        best = math.inf
        for _ in range(3):
            est = StateEstimator(config=EstimatorConfig(fitted_set_as_prior=on))
            t0 = time.process_time()
            for f in frames:
                est.consume(f)
            best = min(best, time.process_time() - t0)
        out[label] = round(1e6 * best / n_pack, 1)
    return out


def main() -> None:
    logging.disable(logging.WARNING)
    fixtures = _fixtures()
    off = _off_prior()
    curved = _set_on_curved_cells()
    print(json.dumps({"fixtures": fixtures, "fixture_takeovers": sum(r["takeovers"] for r in fixtures),
                      "off_prior": off, "off_prior_met": f"{sum(r['met'] for r in off)}/{len(off)}",
                      "set_on_curved_cells": curved,
                      "cpu_us_per_pack_frame": _cpu_per_pack_frame()}))


if __name__ == "__main__":
    main()
