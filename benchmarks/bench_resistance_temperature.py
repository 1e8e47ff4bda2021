"""How much of a PyBaMM cell's loaded sag does an Arrhenius resistance explain? (issue 29)

The hypothesis tested: a warming cell's voltage holds up because its resistance falls, and a
circuit whose series resistance follows R(T) = R_ref exp(E (1/T − 1/T_ref)) would read that as
resistance, not as charge. Measured on the PyBaMM flights themselves, with the truth known: the
sag is the cell's own rested curve at the true SoC less the measured voltage. Per flight, over its
loaded samples after the first minute of load and above SoC 0.15 (away from the knee), least
squares of the sag on a three-timescale circuit — the current now, and its 30 s and 300 s
low-passes (the filter's two polarisation pairs) — with

- ``const``: no temperature factor;
- ``arrhenius``: the factor exp(E u), u = 1/T − 1/298.15, E fitted;
- ``arrhenius_prior``: E the chemistry's prior (``liion``: 3000 K), not fitted.

Reported (the summary over flights that warm at least ``MIN_SPAN_K``): the rms residual of each (mV, pack), the share of the constant fit's residual variance
the fitted factor removes (``explained_by_temperature``), and the fitted E. ``--heldout DIR``
(flights made by ``scripts/generate_pybamm_flights.py --sets ...``, e.g. Ecker2015, Mohtat2020,
NCA_Kim2011: cells no part of the estimator was tuned on; their curves from ``scripts/pybamm_curves.py``
with those sets, into ``DIR/curves.json``) adds those flights, each with its own rested curve when
``DIR/curves.json`` has it, else the ``liion`` table — and, from the ``liion`` prior as the Chen2020
flights are read (``calibration_eval.pybamm_flight_soc``), each one's largest SoC error after 5 min
and its 2σ share (``heldout_soc``).

Run: ``PYTHONPATH=$PWD python benchmarks/bench_resistance_temperature.py [--heldout DIR]`` (≈ 10 s
per dozen flights; the held-out SoC ≈ 2 s a flight). Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CELLS = 5
TAUS_S = (30.0, 300.0)


def _low_pass(current: np.ndarray, dt: np.ndarray, tau: float) -> np.ndarray:
    out = np.zeros_like(current)
    for k in range(1, current.size):
        a = math.exp(-dt[k] / tau)
        out[k] = a * out[k - 1] + (1.0 - a) * current[k]
    return out


def flight_sag_fit(root: Path, flight: dict, sets: dict, table: np.ndarray, prior_e_k: float) -> dict | None:
    """The three fits of one flight's sag (module doc); None when it has too few loaded samples."""
    import pyarrow.parquet as pq
    from scipy.optimize import least_squares

    from gcs_pdm.replay.calibration_eval import pybamm_truth_soc

    cols = pq.read_table(root / flight["file"]).to_pydict()
    t, i, v, temp = (np.asarray(cols[k], dtype=float) for k in ("time_s", "current_a", "voltage_v", "temperature_c"))
    i = np.nan_to_num(i)
    for k in range(1, temp.size):  # a dropped temperature is the last one
        if not math.isfinite(temp[k]):
            temp[k] = temp[k - 1]
    truth = pybamm_truth_soc(t, i, flight, sets[flight["set"]])
    sag = CELLS * np.interp(np.clip(truth, 0.0, 1.0), np.linspace(0.0, 1.0, table.size), table) - v
    dt = np.diff(t, prepend=t[0])
    first_load = int(np.argmax(i > 1.0))
    use = (np.isfinite(v) & np.isfinite(temp) & (i > 3.0) & (np.arange(t.size) > first_load + 60) & (truth > 0.15))
    if use.sum() < 100:
        return None
    basis = np.stack([i, *(_low_pass(i, dt, tau) for tau in TAUS_S)])[:, use]
    u = (1.0 / (temp + 273.15) - 1.0 / 298.15)[use]
    y = sag[use]

    def const(p):
        return p[:3] @ basis - y

    def arrhenius(p):
        return np.exp(p[3] * u) * (p[:3] @ basis) - y

    def arrhenius_prior(p):
        return np.exp(prior_e_k * u) * (p[:3] @ basis) - y

    start = [0.01, 0.01, 0.01]
    fit_c = least_squares(const, start)
    fit_a = least_squares(arrhenius, start + [prior_e_k])
    fit_p = least_squares(arrhenius_prior, start)
    rms = lambda r: round(1000.0 * math.sqrt(float(np.mean(r ** 2))), 1)  # noqa: E731
    return {"flight": flight["flight"], "temperature_c": [round(float(temp[use].min()), 1), round(float(temp[use].max()), 1)],
            "sag_v": round(float(y.mean()), 3), "sag_sd_v": round(float(y.std()), 3),
            "rms_mv": {"const": rms(fit_c.fun), "arrhenius": rms(fit_a.fun), "arrhenius_prior": rms(fit_p.fun)},
            "explained_by_temperature": round(1.0 - float(np.var(fit_a.fun) / np.var(fit_c.fun)), 2),
            "fitted_e_k": round(float(fit_a.x[3]))}


def _curve_of(root: Path, set_name: str) -> np.ndarray:
    from gcs_pdm.models.chemistry import chemistry
    from gcs_pdm.replay.calibration_eval import pybamm_cell_curve

    curves = root / "curves.json"
    if curves.exists() and set_name in json.loads(curves.read_text()).get("sets", {}):
        return pybamm_cell_curve(root, set_name, "liion").table
    return chemistry("liion").table


def measure(root: Path, sets_wanted: set[str] | None) -> list[dict]:
    from gcs_pdm.models.chemistry import chemistry

    manifest = json.loads((root / "manifest.json").read_text())
    prior_e = chemistry("liion").r_activation_k
    rows = []
    for flight in manifest["flights"]:
        if sets_wanted and flight["set"] not in sets_wanted:
            continue
        row = flight_sag_fit(root, flight, manifest["sets"], _curve_of(root, flight["set"]), prior_e)
        if row:
            rows.append(row)
            print(f"{row['flight']}: T {row['temperature_c']} °C, sag {row['sag_v']} ± {row['sag_sd_v']} V, rms mV "
                  f"{row['rms_mv']}, explained by temperature {row['explained_by_temperature']}, E {row['fitted_e_k']} K")
    return rows


#: a flight whose pack warms less than this over its loaded samples cannot show a temperature factor
MIN_SPAN_K = 5.0


def _summary(all_rows: list[dict]) -> dict:
    rows = [r for r in all_rows if r["temperature_c"][1] - r["temperature_c"][0] >= MIN_SPAN_K]
    if not rows:
        return {"flights": len(all_rows), "warming_flights": 0}
    worse = sum(r["rms_mv"]["arrhenius_prior"] > r["rms_mv"]["const"] for r in rows)
    return {"flights": len(all_rows), "warming_flights": len(rows),
            "explained_by_temperature_median": float(np.median([r["explained_by_temperature"] for r in rows])),
            "explained_by_temperature_range": [min(r["explained_by_temperature"] for r in rows),
                                               max(r["explained_by_temperature"] for r in rows)],
            "fitted_e_k_median": float(np.median([r["fitted_e_k"] for r in rows])),
            "fitted_e_k_range": [min(r["fitted_e_k"] for r in rows), max(r["fitted_e_k"] for r in rows)],
            "prior_e_worse_than_none": f"{worse}/{len(rows)}"}


def heldout_soc(root: Path) -> list[dict]:
    """Each flight of ``root`` through the estimator from the ``liion`` prior: largest |SoC error|
    after 5 min and the share inside 2σ."""
    from gcs_pdm.replay.calibration_eval import pybamm_flight_soc

    manifest = json.loads((root / "manifest.json").read_text())
    rows = []
    for flight in manifest["flights"]:
        track, _ = pybamm_flight_soc(root, flight, manifest["sets"], chemistry="liion")
        s = track.summary(300.0)
        rows.append({"flight": flight["flight"], "max_abs_error_after_5min": s["max_abs_error"],
                     "within_2sd": s["within_2sd"]})
        print(f"{flight['flight']} (liion prior): max error {s['max_abs_error']} after 5 min, 2σ {s['within_2sd']}")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--heldout", type=Path, default=None, help="a directory of generated PyBaMM flights")
    args = ap.parse_args()
    out = {"chen2020": _summary(chen := measure(ROOT / "fixtures" / "pybamm", {"Chen2020"})), "chen2020_flights": chen}
    if args.heldout:
        held = measure(args.heldout, None)
        out["heldout"], out["heldout_flights"] = _summary(held), held
        soc = heldout_soc(args.heldout)
        out["heldout_soc_within_0.05"] = f"{sum(r['max_abs_error_after_5min'] <= 0.05 for r in soc)}/{len(soc)}"
        out["heldout_soc"] = soc
    print(json.dumps(out))


if __name__ == "__main__":
    main()
