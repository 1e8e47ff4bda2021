"""The pack's own history as the next flight's prior, on Li-ion cells no fixture holds (issue 29).

Each set's flights (``--heldout DIR``, made by ``scripts/generate_pybamm_flights.py``: by default
``/tmp/chen29_heldout``, Ecker2015, Mohtat2020 and NCA_Kim2011, whose rests around a flight are 30-60 s;
``--rest-around-s 60 900`` makes the same cells' flights with the rests a health point's capacity
needs) stand for ONE pack's successive flights. Every flight is in turn flight 1: it is flown from
the chemistry prior only, its record becomes the pack's health point through the product's own call
(``packs.cell_curves.pack_health_point``, as the live service makes it at a flight's end: the
capacity between the rests, the resistance, the curve fit), the health point goes through
``packs.trend.estimator_priors`` and ``packs.priors.prior_with_history``, and every OTHER flight of
the set is flown from that prior (flight 2, ``pybamm_flight_soc``: the product's path). ``chain``:
flight k from the history of flights 1 … k−1 in order (the store's latest known capacity).

The ``liion`` table is, for each cell, the mean of the OTHER published curves (as
``bench_heldout_cells.py --family``): the shipped table holds these cells' own curves, and a pack
nobody measured would not be on it.

Flight 2's priors (each row's figures: within 0.05 of the truth from 5 min on, median largest error,
mean share inside 2σ, time to cut-off within 10 % at half-way on the flights that reach it):

- ``chemistry``: no history (the table, the nominal capacity, σ 25 %);
- ``history``: the product as it is (capacity read on the LG M50's electrodes, ``packs/cell_curves.py``);
- ``history_point_sd``: the history's capacity with the health point's own σ only, as before
  2026-11-28 (``packs.priors.borrowed_curve_capacity_rel_sd`` now adds the σ of reading the rests
  through a curve that is not the pack's);
- ``history_family_curve``: the health point's capacity read on the ``liion`` table's full-cell curve
  (the family's mean, what the filter uses) instead of the M50's electrodes;
- ``history_fit_capacity``: the curve fit's capacity (``packs.flight_curve``) where the health point
  has none (rests too short): what ``packs.priors`` drops for a chemistry with one curve;
- ``true_capacity``: the true window capacity, σ 2 % (what a perfect history's capacity could give).

Run: ``PYTHONPATH=$PWD python benchmarks/bench_history_prior.py [--heldout DIR] [--chen]``
(``--chen``: the fixtures' Chen2020 set too; 64 s on the rested set, 2 min 36 s on the chen29 set with
``--chen``, load 1-2.5). Prints one line per (set, flight 1), then ONE JSON object. Figures:
docs/notes/2026-11-28-history-prior.md.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
CELLS = 5
VARIANTS = ("chemistry", "history", "history_point_sd", "history_family_curve", "history_fit_capacity",
            "true_capacity")
#: the true capacity's σ in ``true_capacity``
TRUE_CAPACITY_REL_SD = 0.02


def curve_point(pack_id: str, table: dict, nominal_ah: float, ocv_cell_v=None):
    """The health point with its capacity read on a full-cell curve: the ``liion`` table's (the
    family's mean, the alternative to the M50's electrodes), or ``ocv_cell_v`` (the cell's own: what
    the rests give with the curve known); ``health_point`` with that curve, as ``cell_curves`` reads
    the chemistries that have no electrodes."""
    from gcs_pdm.models.chemistry import SOC_GRID, chemistry
    from gcs_pdm.packs.health import GENERIC_CURVE_SOC_SD, OcvCurve, health_point

    own = ocv_cell_v is not None
    ocv = OcvCurve(tuple(float(s) for s in SOC_GRID), tuple(ocv_cell_v) if own else chemistry("liion").ocv_cell_v,
                   soc_sd=0.0 if own else GENERIC_CURVE_SOC_SD, name="own" if own else "liion full cell (family mean)")
    return health_point(pack_id, table["time_s"], table["current_a"], table["voltage_v"], table["temperature_c"],
                        nominal_capacity_ah=nominal_ah, cells_series=CELLS, ocv=ocv)


def with_fit_capacity(history: dict) -> dict:
    """``history`` with the curve fit's capacity where the health point has none."""
    fit = history.get("curve") or {}
    if history.get("capacity_ah") is None and fit.get("capacity_ah") and fit.get("capacity_sd_ah"):
        return {**history, "capacity_ah": fit["capacity_ah"], "capacity_sd_ah": fit["capacity_sd_ah"]}
    return history


def rel(value, truth):
    return None if value is None else round(value / truth - 1.0, 3)


def figures(runs: list[dict]) -> dict:
    errs = [r["max_abs_error_after_5min"] for r in runs]
    ttc = [r["ttc_rel_error_at_half"] for r in runs if "ttc_rel_error_at_half" in r]
    return {"within_0.05_after_5min": f"{sum(e <= 0.05 for e in errs)}/{len(errs)}",
            "median_max_abs_error": round(float(np.median(errs)), 3) if errs else None,
            "within_2sd_mean": round(float(np.mean([r["within_2sd_after_5min"] for r in runs])), 3) if runs else None,
            "ttc_within_10pct_at_half": f"{sum(abs(x) <= 0.10 for x in ttc)}/{len(ttc)}",
            "ttc_rel_error_at_half": ttc}


def one_set(root: Path, set_name: str, manifest: dict) -> dict:
    import pyarrow.parquet as pq
    from bench_heldout_cells import flight_through_product, liion_table

    from gcs_pdm.estimation.calibration import PackPrior
    from gcs_pdm.models.liion_family import LIION_PUBLISHED_CURVES, family_mean
    from gcs_pdm.packs.cell_curves import pack_health_point
    from gcs_pdm.packs.priors import prior_with_history
    from gcs_pdm.packs.trend import estimator_priors
    from gcs_pdm.replay.calibration_eval import pybamm_cell_curve

    s = manifest["sets"][set_name]
    nominal_ah = s["cell_capacity_ah"] * s["cells_parallel"]
    true_ah = s["cell_window_capacity_ah"] * s["cells_parallel"]
    flights = [f for f in manifest["flights"] if f["set"] == set_name]
    others = tuple(c for c in LIION_PUBLISHED_CURVES if c.pybamm_set != set_name)
    out = {"nominal_capacity_ah": round(nominal_ah, 3), "true_capacity_ah": round(true_ah, 3), "flights_1": [],
           "flights_2": {v: [] for v in VARIANTS}}
    pack = f"{set_name} pack"
    # the cell's own rested curve, where the directory has the sets' electrode curves (a diagnostic:
    # the rests' capacity with the curve known)
    own_curve = (pybamm_cell_curve(root, set_name, "liion").ocv_cell_v if (root / "curves.json").exists()
                 and set_name in json.loads((root / "curves.json").read_text())["sets"] else None)
    with liion_table(family_mean(others), "mean of " + ", ".join(c.pybamm_set for c in others)):
        base = PackPrior("liion", CELLS, nominal_ah * 3600.0)

        def fly(flight, prior):
            return flight_through_product(root, flight, manifest["sets"], prior=prior)

        alone = {f["flight"]: fly(f, base) for f in flights}
        true_prior = replace(base, capacity_c=true_ah * 3600.0, capacity_rel_sd=TRUE_CAPACITY_REL_SD,
                             capacity_source="truth (bench)")
        truly = {f["flight"]: fly(f, true_prior) for f in flights}
        points = {}
        for first in flights:
            table = pq.read_table(root / first["file"]).to_pydict()
            # the product's own call, as the live service makes it at a flight's end (service/flights.py)
            hp = pack_health_point(pack, table["time_s"], table["current_a"], table["voltage_v"],
                                   table["temperature_c"], chemistry="liion", nominal_capacity_ah=nominal_ah,
                                   cells_series=CELLS, fit_curve=True)
            points[first["flight"]] = hp
            alt = curve_point(pack, table, nominal_ah)
            own = curve_point(pack, table, nominal_ah, own_curve) if own_curve is not None else None
            history = estimator_priors([hp])
            fit = hp.curve or {}
            told = prior_with_history(base, history, pack)
            priors = {"history": told,
                      "history_point_sd": (replace(told, capacity_rel_sd=hp.capacity_sd_ah / hp.capacity_ah)
                                           if hp.capacity_ah else told),
                      "history_family_curve": prior_with_history(
                          base, {**history, "capacity_ah": alt.capacity_ah, "capacity_sd_ah": alt.capacity_sd_ah},
                          pack),
                      "history_fit_capacity": prior_with_history(base, with_fit_capacity(history), pack)}
            row = {"flight_1": first["flight"], "ambient_c": first["ambient_c"],
                   "reached_cutoff": bool(first.get("reached_cutoff")),
                   "health_capacity_ah": hp.capacity_ah, "health_capacity_sd_ah": hp.capacity_sd_ah,
                   "health_capacity_error": rel(hp.capacity_ah, true_ah), "why": hp.why.get("capacity_ah"),
                   "family_curve_capacity_error": rel(alt.capacity_ah, true_ah),
                   "family_curve_capacity_sd_rel": rel(alt.capacity_sd_ah, alt.capacity_ah or 1.0),
                   "fit_capacity_error": rel(fit.get("capacity_ah"), true_ah), "fit_why": fit.get("why"),
                   "own_curve_capacity_error": rel(own.capacity_ah, true_ah) if own is not None else None,
                   "prior_capacity_ah": {k: round(p.capacity_c / 3600.0, 3) for k, p in priors.items()},
                   "prior_capacity_rel_sd": {k: round(p.capacity_rel_sd, 3) for k, p in priors.items()},
                   "prior_r0_ohm": priors["history"].r0_ohm, "base_r0_ohm": base.r0_ohm}
            for name in VARIANTS:
                runs = []
                for second in flights:
                    if second is first:
                        continue
                    r = (alone if name == "chemistry" else truly if name == "true_capacity" else None)
                    runs.append(r[second["flight"]] if r is not None else fly(second, priors[name]))
                out["flights_2"][name] += runs
                row[name] = {k: v for k, v in figures(runs).items() if k != "ttc_rel_error_at_half"}
            out["flights_1"].append(row)
            print(f"{set_name} flight 1 {first['flight']}: health capacity {row['health_capacity_error']} "
                  f"({row['why'] or 'read'}), family curve {row['family_curve_capacity_error']}, own curve "
                  f"{row['own_curve_capacity_error']}, "
                  f"fit {row['fit_capacity_error']}; flights 2 within 0.05: "
                  + ", ".join(f"{v} {row[v]['within_0.05_after_5min']}" for v in VARIANTS), flush=True)
        chain = []
        for k, flight in enumerate(flights[1:], start=1):
            history = estimator_priors([points[f["flight"]] for f in flights[:k]])
            chain.append(fly(flight, prior_with_history(base, history, pack)))
        out["chain"] = figures(chain)
        out["chain_chemistry"] = figures([alone[f["flight"]] for f in flights[1:]])
    out["summary"] = {v: figures(runs) for v, runs in out.pop("flights_2").items()}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heldout", type=Path, default=Path("/tmp/chen29_heldout"))
    ap.add_argument("--chen", action="store_true", help="also the fixtures' Chen2020 flights (fixtures/pybamm)")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # each suspended voltage model warns once; the figures say it
    sources = []
    manifest = json.loads((args.heldout / "manifest.json").read_text())
    sources += [(args.heldout, name, manifest) for name in manifest["sets"]]
    if args.chen:
        fixtures = ROOT / "fixtures" / "pybamm"
        sources.append((fixtures, "Chen2020", json.loads((fixtures / "manifest.json").read_text())))
    result = {"heldout": str(args.heldout), "sets": {}}
    for root, name, man in sources:
        result["sets"][name] = one_set(root, name, man)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
