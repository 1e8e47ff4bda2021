"""Is the time to cut-off's interval true? (issue 29: a self-calibrated pack's count-down).

For the count-down the product shows for a pack nobody fitted (``estimation.calibrated_cutoff``:
the median and 5-95 % of ``TRACE_SAMPLES`` draws), at half-way and every minute after it while a
minute is left, against the time truly left:

- ``pybamm``: the PyBaMM flights that reach cut-off (``fixtures/pybamm``), from a chemistry prior
  only (``calibration_eval.pybamm_flight_soc``);
- ``simulated``: each self-calibrating preset's pack on its chemistry's curve, off its label as
  ``bench_soc_calibration.SIM_CASES`` (capacity 0.7-1.3x, resistance 0.5-3x, starts 50-100 %),
  flown at 1.5 C ± 10 % legs to its cut-off (``calibration_eval.simulated_cutoff_case``).

Per set, for the product (``product``) and for the draws of the filter's covariance alone
(``filter_only``: the load held exactly, the model's shortfall at its mean, LLF20's rise — the
interval before the unmodelled terms were drawn): the share of predictions whose 5-95 % holds the
truth (nominal 90 %), the share whose median is within 10 %, and the median relative half-width
((95 % − 5 %) / 2 over the time truly left); at half-way alone and over every prediction.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_time_to_cutoff.py [--sets pybamm,simulated]``
(its `cpu_s` ≈ 11 s; 4-5 min wall at load 8). Prints one line per flight or case, then ONE JSON object.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
VARIANTS = ("later", "later_filter_only")


def figures(runs: list[dict]) -> dict:
    """Coverage, within-10 % and median relative half-width, at half-way and over every prediction."""
    out = {}
    for key in VARIANTS:
        name = "product" if key == "later" else "filter_only"
        for scope in ("at_half", "all"):
            rows = [r[key][0] for r in runs if r[key]] if scope == "at_half" else [x for r in runs for x in r[key]]
            t, lo, med, hi = (np.array(c, dtype=float) for c in zip(*rows)) if rows else [np.array([])] * 4
            width = (hi - lo) / 2.0 / t
            out[f"{name}_{scope}"] = {
                "predictions": len(rows),
                "interval_holds_truth": f"{int(((lo <= t) & (t <= hi)).sum())}/{len(rows)}",
                "median_within_10pct": f"{int((np.abs(med / t - 1.0) <= 0.10).sum())}/{len(rows)}",
                "median_relative_half_width": round(float(np.median(width)), 3) if rows else None}
    return out


def _pybamm() -> list[dict]:
    from gcs_pdm.replay.calibration_eval import pybamm_flight_soc

    root = ROOT / "fixtures" / "pybamm"
    manifest = json.loads((root / "manifest.json").read_text())
    runs = []
    for flight in [f for f in manifest["flights"] if f.get("reached_cutoff")]:
        _, ttc = pybamm_flight_soc(root, flight, manifest["sets"])
        runs.append({"case": flight["flight"], **{k: ttc.get(k, []) for k in VARIANTS}})
        _print(runs[-1])
    return runs


def _simulated() -> list[dict]:
    from bench_soc_calibration import PRESETS, SIM_CASES

    from gcs_pdm.replay.calibration_eval import simulated_cutoff_case

    runs = []
    for preset in [p for p in PRESETS if p != "edge540"]:  # edge540 keeps its fitted set's filter
        for cap, res, start, seed in SIM_CASES:
            got = simulated_cutoff_case(preset, capacity_scale=cap, resistance_scale=res, start_soc=start, seed=seed)
            runs.append({"case": f"{preset} C x{cap} R x{res} from {start}", **got})
            _print(runs[-1])
    return runs


def _print(run: dict) -> None:
    for key in VARIANTS:
        rows = run[key]
        held = sum(lo <= t <= hi for t, lo, _, hi in rows)
        first = ", ".join(f"{x:.0f}" for x in rows[0]) if rows else "none"
        print(f"{run['case']} {key}: holds {held}/{len(rows)}; at half-way (true, 5/50/95 %) {first}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", default="pybamm,simulated")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # each suspended voltage model warns once; the figures say it
    started = time.process_time()
    summary = {}
    for name, run in (("pybamm", _pybamm), ("simulated", _simulated)):
        if name in args.sets.split(","):
            runs = run()
            summary[name] = figures(runs)
            summary[f"{name}_runs"] = runs
    summary["cpu_s"] = round(time.process_time() - started, 1)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
