"""The pack's own history as the next flight's prior, on the PyBaMM flights (issue 29).

Each set's flights are one pack's: flight 1 (every flight that drew at least ``MIN_DRAWN_FRACTION``
of the rated capacity) is fitted after it lands (``packs.flight_curve.fit_flight_curve``: curve,
offset, scale, capacity), the record goes through ``packs.priors.prior_with_history`` as the live
service's does, and every *other* flight of the set is flown from that prior (flight 2). Per
flight 1: flights 2 within 0.05 of the truth after 5 min, their median largest error, the mean
share inside 2σ. Rows: the charge voltage declared (Marquis2019 4.10 V, Chen2020 4.20 V: what the
description's ``full_cell_voltage`` gives) or not; and the chemistry prior alone (no history) for
comparison. A chemistry with one published curve (Chen2020's ``liion``) is given nothing by the fit
(``packs.priors``: its flights 2 are the chemistry prior's, ``applied`` false): its rows check that.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_pack_history_prior.py [--sets Marquis2019]``
(≈ 4 min per set at load 12). Prints one line per (set, flight 1, declared), then ONE JSON object.
"""
from __future__ import annotations

import argparse
import json
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DECLARED_FULL_CELL_V = {"Chen2020": 4.20, "Marquis2019": 4.10}
CELLS = 5


def main() -> None:
    import pyarrow.parquet as pq

    from gcs_pdm.estimation.calibration import PackPrior
    from gcs_pdm.packs.flight_curve import fit_flight_curve
    from gcs_pdm.packs.priors import prior_with_history
    from gcs_pdm.replay.calibration_eval import PYBAMM_CHEMISTRY, pybamm_flight_soc

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", nargs="+", default=["Marquis2019", "Chen2020"])
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    root = ROOT / "fixtures" / "pybamm"
    manifest = json.loads((root / "manifest.json").read_text())
    result: dict = {}
    for set_name in args.sets:
        s = manifest["sets"][set_name]
        chem = PYBAMM_CHEMISTRY[set_name]
        nominal_c = s["cell_capacity_ah"] * s["cells_parallel"] * 3600.0
        true_ah = s["cell_window_capacity_ah"] * s["cells_parallel"]
        flights = [f for f in manifest["flights"] if f["set"] == set_name]
        out = result.setdefault(set_name, {"true_capacity_ah": round(true_ah, 3), "runs": []})

        def fly(flight, prior):
            track, _ = pybamm_flight_soc(root, flight, manifest["sets"], prior=prior, cells=CELLS)
            return track.summary(300.0)

        base = PackPrior(chem, CELLS, nominal_c)
        alone = {f["flight"]: fly(f, base) for f in flights}
        out["chemistry_prior_alone"] = {"within_0.05": sum(a["max_abs_error"] <= 0.05 for a in alone.values()),
                                        "of": len(alone)}
        for declared in (DECLARED_FULL_CELL_V[set_name], None):
            described = replace(base, full_cell_v=declared)
            for first in flights:
                table = pq.read_table(root / first["file"]).to_pydict()
                fit = fit_flight_curve(table["time_s"], table["current_a"], table["voltage_v"], table["temperature_c"],
                                       described)
                if fit.get("why"):
                    continue
                prior = prior_with_history(described, {"curve": fit}, "bench pack")
                seconds = [fly(f, prior) for f in flights if f is not first]
                errors = [x["max_abs_error"] for x in seconds]
                row = {"declared_full_cell_v": declared, "flight_1": first["flight"],
                       "flight_1_reached_cutoff": bool(first.get("reached_cutoff")),
                       "fit": {k: fit[k] for k in ("curve", "weight", "ocv_offset_v", "ocv_scale", "capacity_ah",
                                                   "capacity_sd_ah", "start_soc", "started_full")},
                       "fit_capacity_error": round(fit["capacity_ah"] / true_ah - 1.0, 3),
                       "fit_start_soc_error": round(fit["start_soc"] - first["initial_soc"], 3),
                       "applied": prior is not described,
                       "flights_2_within_0.05": sum(e <= 0.05 for e in errors), "flights_2": len(errors),
                       "median_max_abs_error": round(float(np.median(errors)), 3),
                       "within_2sd_mean": round(float(np.mean([x["within_2sd"] for x in seconds])), 3)}
                out["runs"].append(row)
                print(f"{set_name} declared {declared} flight 1 {first['flight']} (cut-off {row['flight_1_reached_cutoff']}): "
                      f"fit {row['fit']['curve']} w {row['fit']['weight']}, offset {fit['ocv_offset_v']}, scale "
                      f"{fit['ocv_scale']}, capacity {fit['capacity_ah']} Ah ({row['fit_capacity_error']:+.3f}), start "
                      f"{fit['start_soc']} ({row['fit_start_soc_error']:+.3f}); flights 2 within 0.05 "
                      f"{row['flights_2_within_0.05']}/{row['flights_2']}, median {row['median_max_abs_error']}, "
                      f"inside 2σ {row['within_2sd_mean']}", flush=True)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
