"""How well the packs' health points and forecast follow PyBaMM's ageing cells (fixtures/pybamm_ageing).

    python scripts/evaluate_pack_ageing.py [--fixtures fixtures/pybamm_ageing]

Per parameter set: each flight's capacity estimate against the cell's true C/20 capacity at that age
(error, and whether the truth lies within 2σ); the resistance estimates against the true 1-s
resistance at the take-off step, the one the health point reads (rank correlation, growth last half
/ first half of each, error), and against the small-signal one at the rest-to-idle step that opens
the flight; and the retirement forecast (80 % of the first capacity) made from the flights of the
first half of life against the equivalent cycles at which the truth crossed 80 %. Each flight's
point is made as the live service and ``packs ingest`` make a ``liion`` pack's (``packs.cell_curves.pack_health_point``: the LG M50 electrodes of
Chen2020, fresh, scaled to the rated capacity); nothing about the ageing. ``--own-electrodes``:
each set's own fresh electrodes from the manifest instead (O'Kane2022's graphite curve is not
Chen2020's). Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gcs_pdm.packs.cell_curves import pack_health_point  # noqa: E402
from gcs_pdm.packs.health import ElectrodeCurves, health_point  # noqa: E402
from gcs_pdm.packs.trend import cumulative_cycles, pack_trend  # noqa: E402


def electrodes_of(entry: dict) -> ElectrodeCurves:
    e = entry["electrodes"]
    return ElectrodeCurves(tuple(e["stoichiometry"]), tuple(e["negative_v"]), tuple(e["positive_v"]),
                           e["negative_ah"], e["positive_ah"], entry["lower_cutoff_v"], name="fresh electrodes")


def spearman(a, b) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def evaluate(fixtures: Path, sets=None, own_electrodes: bool = False) -> dict:
    import pandas as pd

    man = json.loads((fixtures / "manifest.json").read_text())
    out = {}
    for set_name, entry in man["sets"].items():
        if sets and set_name not in sets:
            continue
        el = electrodes_of(entry)
        flights = [f for f in man["flights"] if f["set"] == set_name]
        points = []
        for f in flights:
            df = pd.read_parquet(fixtures / f["file"])
            series = (df.time_s.to_numpy(), df.current_a.to_numpy(), df.voltage_v.to_numpy(), df.temperature_c.to_numpy())
            nominal = entry["nominal_cell_capacity_ah"]
            points.append(health_point(set_name, *series, nominal_capacity_ah=nominal, electrodes=el) if own_electrodes
                          else pack_health_point(set_name, *series, chemistry="liion", nominal_capacity_ah=nominal))
        true_c = np.array([f["true_capacity_ah"] for f in flights])
        est_c = np.array([np.nan if p.capacity_ah is None else p.capacity_ah for p in points])
        sd_c = np.array([np.nan if p.capacity_sd_ah is None else p.capacity_sd_ah for p in points])
        err = est_c / true_c - 1.0
        # the resistance truths: the 1-s step at the take-off step (what the health point reads)
        # and the small-signal one at the rest-to-idle step that opens the flight
        true_r = np.array([f["true_takeoff_resistance_ohm"] for f in flights], float)
        true_r_small = np.array([f["true_pulse_resistance_ohm"] for f in flights], float)
        est_r = np.array([np.nan if p.resistance_25c_ohm is None else p.resistance_25c_ohm for p in points])
        cycles = cumulative_cycles(points)
        # the truth's crossing of 80 % of its first capacity, in equivalent cycles
        below = np.flatnonzero(true_c <= 0.8 * true_c[0])
        n80 = None
        if below.size:
            k = int(below[0])
            w = (true_c[k - 1] - 0.8 * true_c[0]) / (true_c[k - 1] - true_c[k])
            n80 = float(cycles[k - 1] + w * (cycles[k] - cycles[k - 1]))
        forecast = None
        if n80 is not None:
            half = [p for p, c in zip(points, cycles) if c <= n80 / 2.0]
            t = pack_trend(set_name, half, capacity_fraction=0.8, resistance_factor=1.5)
            f = t.capacity_forecast
            forecast = {"flights_used": len(half), "forecast_cycles": f.cycles, "low": f.low, "high": f.high,
                        "true_cycles": n80,
                        "error": None if f.cycles is None else f.cycles / n80 - 1.0,
                        "truth_in_interval": None if f.cycles is None else bool(
                            (f.low or 0) <= n80 <= (f.high if f.high is not None else np.inf))}
        half_r = len(flights) // 2
        out[set_name] = {
            "flights": len(flights), "options": entry["options"],
            "capacity_true_first_last": [float(true_c[0]), float(true_c[-1])],
            "capacity_abs_error_max": float(np.nanmax(np.abs(err))),
            "capacity_abs_error_mean": float(np.nanmean(np.abs(err))),
            "capacity_error_mean_signed": float(np.nanmean(err)),
            "capacity_within_3pct": int(np.sum(np.abs(err) <= 0.03)),
            "capacity_truth_within_2sd": int(np.sum(np.abs(est_c - true_c) <= 2 * sd_c)),
            "capacity_errors": [round(float(x), 4) for x in err],
            "resistance_rank_correlation": spearman(est_r, true_r),
            "resistance_growth_true": float(np.mean(true_r[-half_r:]) / np.mean(true_r[:half_r])),
            "resistance_growth_estimated": float(np.nanmean(est_r[-half_r:]) / np.nanmean(est_r[:half_r])),
            "resistance_error_mean": float(np.nanmean(est_r / true_r - 1.0)),
            "resistance_abs_error_max": float(np.nanmax(np.abs(est_r / true_r - 1.0))),
            "resistance_small_step_rank_correlation": spearman(est_r, true_r_small),
            "resistance_small_step_growth_true": float(np.mean(true_r_small[-half_r:]) / np.mean(true_r_small[:half_r])),
            "equivalent_cycles": float(cycles[-1] + points[-1].equivalent_cycles),
            "forecast_from_first_half": forecast,
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fixtures", default=str(REPO / "fixtures" / "pybamm_ageing"))
    ap.add_argument("--sets", nargs="*", default=None, help="only these parameter sets")
    ap.add_argument("--own-electrodes", action="store_true",
                    help="each set's own fresh electrodes (the manifest's), not the liion chemistry's")
    args = ap.parse_args(argv)
    res = evaluate(Path(args.fixtures), args.sets, args.own_electrodes)
    for name, r in res.items():
        print(f"{name}: capacity error max {r['capacity_abs_error_max']:.2%} mean {r['capacity_abs_error_mean']:.2%} "
              f"(signed {r['capacity_error_mean_signed']:+.2%}), "
              f"{r['capacity_within_3pct']}/{r['flights']} within 3 %, truth within 2σ in "
              f"{r['capacity_truth_within_2sd']}; resistance at the take-off step: rank correlation "
              f"{r['resistance_rank_correlation']:.2f}, growth true {r['resistance_growth_true']:.2f} est "
              f"{r['resistance_growth_estimated']:.2f}, error mean {r['resistance_error_mean']:+.1%} worst "
              f"{r['resistance_abs_error_max']:.1%} (small-signal truth: growth "
              f"{r['resistance_small_step_growth_true']:.2f}, rank correlation "
              f"{r['resistance_small_step_rank_correlation']:.2f}); "
              f"forecast {r['forecast_from_first_half']}")
    print(json.dumps({"evaluation": "pack_ageing", **res}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
