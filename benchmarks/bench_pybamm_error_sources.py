"""Which part of the chemistry prior costs the PyBaMM flights their SoC (issue 29, item 2).

Each PyBaMM flight (``fixtures/pybamm``) goes through the self-calibrating filter six times, from
priors that differ in one part at a time:

- ``chemistry``: what the product starts from (the chemistry's table, the nominal capacity, σ 25 %);
- ``own_curve``: the cell's own rested curve (``calibration_eval.pybamm_cell_curve``) in place of
  the chemistry's table, the rest as ``chemistry``;
- ``true_capacity``: the cell's true window capacity with σ 2 %, the chemistry's table;
- ``both``: the own curve and the true capacity;
- ``declared_full``: the chemistry's curve whose full cell is the set's declared upper voltage
  (``PackPrior.full_cell_v``: what a user who knows the cell's charge voltage writes in the
  description; Marquis2019's 4.10 V picks the LCO pouch charged to 4.10 V, ``models.curve_hypotheses``),
  the nominal capacity; ``declared_full_true_capacity``: that and the true capacity (σ 2 %): what
  the published curve leaves when everything else is right.

``chemistry`` of a LiPo runs the curve bank (``estimation.curve_bank``): its hypotheses weighed by
the voltage.

What is left with ``both`` is the circuit's (resistance, polarisation, temperature). Per set and
prior: flights within 0.05 after 5 min, the median of the largest error after 5 min, the mean share
of samples after 5 min whose 2σ band holds the truth, and flights whose time to cut-off from
half-way (what the product shows: ``calibrated_cutoff``'s median of its draws) is within 10 %, and
whose 5-95 % interval holds the truth.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_pybamm_error_sources.py`` (≈ 1 min). Prints one line
per set and prior, then ONE JSON object.
"""
from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRIORS = ("chemistry", "own_curve", "true_capacity", "both", "declared_full", "declared_full_true_capacity")
#: the charge voltage each set declares (its PyBaMM set's upper voltage cut-off)
DECLARED_FULL_CELL_V = {"Chen2020": 4.20, "Marquis2019": 4.10}


def main() -> None:
    from gcs_pdm.estimation.calibration import PackPrior
    from gcs_pdm.replay.calibration_eval import PYBAMM_CHEMISTRY, pybamm_cell_curve, pybamm_flight_soc

    logging.disable(logging.WARNING)  # each suspended voltage model warns once; the figures say it
    root = ROOT / "fixtures" / "pybamm"
    manifest = json.loads((root / "manifest.json").read_text())
    cells = 5
    result: dict = {}
    for set_name, s in manifest["sets"].items():
        chem = PYBAMM_CHEMISTRY[set_name]
        nominal_c = s["cell_capacity_ah"] * s["cells_parallel"] * 3600.0
        true_c = s["cell_window_capacity_ah"] * s["cells_parallel"] * 3600.0
        base = PackPrior(chem, cells, nominal_c)
        own = pybamm_cell_curve(root, set_name, chem)
        priors = {"chemistry": base, "own_curve": replace(base, curve=own),
                  "true_capacity": replace(base, capacity_c=true_c, capacity_rel_sd=0.02),
                  "both": replace(base, curve=own, capacity_c=true_c, capacity_rel_sd=0.02),
                  "declared_full": replace(base, full_cell_v=DECLARED_FULL_CELL_V[set_name]),
                  "declared_full_true_capacity": replace(base, full_cell_v=DECLARED_FULL_CELL_V[set_name],
                                                         capacity_c=true_c, capacity_rel_sd=0.02)}
        flights = [f for f in manifest["flights"] if f["set"] == set_name]
        for name in PRIORS:
            errors, ttc_errors, ttc_held, inside = [], [], [], []
            for flight in flights:
                track, ttc = pybamm_flight_soc(root, flight, manifest["sets"], prior=priors[name], cells=cells)
                summary = track.summary(300.0)
                errors.append(summary["max_abs_error"])
                inside.append(summary["within_2sd"])
                if ttc and ttc["true_s"] > 0 and np.isfinite(ttc["predicted_s"]):
                    ttc_errors.append(ttc["predicted_s"] / ttc["true_s"] - 1.0)
                    ttc_held.append(ttc["low_s"] <= ttc["true_s"] <= ttc["high_s"])
            row = {"within_0.05_after_5min": f"{sum(e <= 0.05 for e in errors)}/{len(errors)}",
                   "median_max_abs_error": round(float(np.median(errors)), 3),
                   "max_abs_errors": [round(e, 3) for e in errors],
                   "within_2sd_mean": round(float(np.mean(inside)), 3),
                   "time_to_cutoff_within_10pct": f"{sum(abs(e) <= 0.10 for e in ttc_errors)}/{len(ttc_errors)}",
                   "time_to_cutoff_rel_errors": [round(e, 3) for e in ttc_errors],
                   "time_to_cutoff_interval_holds_truth": f"{sum(ttc_held)}/{len(ttc_held)}"}
            result.setdefault(set_name, {})[name] = row
            print(f"{set_name} {name}: within 0.05 {row['within_0.05_after_5min']}, median largest error "
                  f"{row['median_max_abs_error']}, within 2σ {row['within_2sd_mean']}, time to cut-off within 10 % "
                  f"{row['time_to_cutoff_within_10pct']} {row['time_to_cutoff_rel_errors']}, its 5-95 % holds the "
                  f"truth {row['time_to_cutoff_interval_holds_truth']}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
