"""Diagnosis: is the extended circuit's error on the PyBaMM flights its structure or its learned curve?

Development tool (docs/fitting.md, "What limits the extended circuit"). It holds the cells' *true*
open-circuit curves (``fixtures/pybamm/curves.json``, written by ``scripts/pybamm_curves.py``) and
learns only the circuit around them, by least squares on the training flights, for two structures:

* ``one_surface`` - the product's extended circuit (docs/model.md): the whole open-circuit curve read
  at one surface SoC, SoC - s_d;
* ``two_electrodes`` - each electrode's potential read at its own surface: U_p at SoC - d_p (the
  cathode, deep and slow) minus U_n at SoC - d_n (the graphite anode, shallow and fast), each
  depletion I k / C_max relaxing with its own time constant.

Everything else (R_0, two R-C pairs, Arrhenius resistance, Butler-Volmer kinetics with its own
activation and the low-charge rise, capacity) is the extended circuit's. With the curves given, a
structure that cannot fit the training flights is short in structure, not in data. It then predicts
the test flights from three starts: the product's reading (the first 10 rest samples through the
curve), the whole steady rest, and the generator's true initial SoC.

    PYTHONPATH=$PWD python scripts/diagnose_model_structure.py --set Chen2020 --starts 3

The last line is the figures as one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from numba import njit
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs_pdm.fitting.cleaning import clean_flights  # noqa: E402
from gcs_pdm.fitting.logs import read_table  # noqa: E402
from gcs_pdm.fitting.problem import STEADY_CURRENT_A, prepare  # noqa: E402

CELLS = 5
T_REF_K = 298.15
NAMES = ("R_0", "R_1", "tau_1", "R_2", "tau_2", "E_r", "E_ct", "k_soc", "soc_knee", "b_ct", "i_ct",
         "k_p", "tau_p", "k_n", "tau_n", "C_max", "E_d")
LO = np.array([1e-3, 1e-4, 1.0, 1e-4, 30.0, 100.0, 100.0, 1e-3, 0.01, 1e-3, 0.1, 0.1, 5.0, 0.1, 1.0, 0.7 * 28080, 1.0])
HI = np.array([0.2, 0.2, 100.0, 0.2, 3000.0, 8000.0, 8000.0, 10.0, 0.3, 1.0, 500.0, 3000.0, 20000.0, 3000.0, 2000.0,
               1.4 * 28080, 8000.0])
STRUCTURES = ("one_surface", "two_electrodes", "two_electrodes_activated")


@njit  # no cache: the test loads this file by path, where a cached entry cannot be rebuilt
def simulate(p, two, soc0, dt, current, temperature, grid, pos, neg, window, out, activated=False):
    """Terminal voltage (V, pack) of one flight; ``window`` = (x_0, x_100, y_0, y_100)."""
    r0, r1, tau1, r2, tau2, e_r, e_ct, k_soc, knee, b_ct, i_ct, k_p, tau_p, k_n, tau_n, c_max, e_d = p
    x_0, x_100, y_0, y_100 = window
    soc, v1, v2, d_p, d_n = soc0, 0.0, 0.0, 0.0, 0.0
    for k in range(current.shape[0]):
        h, i, t_k = dt[k], current[k], temperature[k] + 273.15
        soc -= i * h / c_max
        # solid diffusion slows in the cold: depth and time constant both scale with 1/D(T)
        slow = math.exp(e_d * (1.0 / t_k - 1.0 / T_REF_K)) if activated else 1.0
        d_p = i * k_p * slow / c_max + (d_p - i * k_p * slow / c_max) * math.exp(-h / (tau_p * slow))
        d_n = i * k_n * slow / c_max + (d_n - i * k_n * slow / c_max) * math.exp(-h / (tau_n * slow))
        deep = soc - d_p
        shallow = soc - d_n if two else deep   # one surface: both electrodes read at the deep one
        ocv = CELLS * (np.interp(y_0 + deep * (y_100 - y_0), grid, pos) - np.interp(x_0 + shallow * (x_100 - x_0), grid, neg))
        rho = 1.0 + k_soc * math.exp(-max(deep, 0.0) / knee)
        f = math.exp(e_r * (1.0 / t_k - 1.0 / T_REF_K)) * rho
        g = math.exp(e_ct * (1.0 / t_k - 1.0 / T_REF_K)) * rho
        v1 = i * r1 * f + (v1 - i * r1 * f) * math.exp(-h / tau1)
        v2 = i * r2 * f + (v2 - i * r2 * f) * math.exp(-h / tau2)
        out[k] = ocv - i * r0 * f - b_ct * (t_k / T_REF_K) * math.asinh(i * g / i_ct) - v1 - v2
    return out


def pack_ocv(c: dict, grid: np.ndarray, soc: np.ndarray) -> np.ndarray:
    """Open-circuit voltage (V, pack) at ``soc`` of one set's curves ``c`` (a ``curves.json`` set)."""
    return CELLS * (np.interp(c["y_0"] + soc * (c["y_100"] - c["y_0"]), grid, c["positive_v"])
                    - np.interp(c["x_0"] + soc * (c["x_100"] - c["x_0"]), grid, c["negative_v"]))


def leading_rest(pv) -> int:
    """Samples before the current first leaves rest (the product's steady-current threshold)."""
    return int(np.argmax(np.abs(pv.current) > STEADY_CURRENT_A))


def load(set_name: str) -> tuple[dict, dict, dict]:
    manifest = json.loads((ROOT / "fixtures/pybamm/manifest.json").read_text())
    curves = json.loads((ROOT / "fixtures/pybamm/curves.json").read_text())
    flights = {}
    for entry in (f for f in manifest["flights"] if f["set"] == set_name):
        (flight,), _, _ = clean_flights([read_table(ROOT / "fixtures/pybamm" / entry["file"], "battery", entry["flight"])])
        flights[entry["flight"]] = (entry, prepare(flight, "voltage", 10))
    return flights, curves, curves["sets"][set_name]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="Chen2020", choices=("Chen2020", "Marquis2019"))
    ap.add_argument("--starts", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-nfev", type=int, default=400)
    ap.add_argument("--structures", nargs="+", default=list(STRUCTURES), choices=STRUCTURES)
    args = ap.parse_args(argv)
    flights, curves, c = load(args.set)
    grid = np.array(curves["stoichiometry"])
    pos, neg = np.array(c["positive_v"]), np.array(c["negative_v"])
    window = np.array([c["x_0"], c["x_100"], c["y_0"], c["y_100"]])
    socs = np.linspace(-0.05, 1.05, 4401)
    ocv = pack_ocv(c, grid, socs)

    def rest_soc(pv, whole: bool) -> float:
        # the first 10 rest samples, as the product reads them (prepare), or the whole leading rest
        v = float(np.nanmean(pv.target[:leading_rest(pv)])) if whole else pv.init_voltage
        return float(np.interp(v, ocv, socs))

    def trace(p, structure, pv, soc0):
        return simulate(p, structure != "one_surface", soc0, pv.dt, pv.current, pv.drive_temperature, grid, pos, neg,
                        window, np.empty(pv.current.size), structure == "two_electrodes_activated")

    def rmse(v, pv):
        return float(np.sqrt(np.mean((v[pv.mask] - pv.target[pv.mask]) ** 2)))

    train = [pv for e, pv in flights.values() if e["split"] == "train"]
    train_starts = [rest_soc(pv, False) for pv in train]   # the curves are held: the starts do not move
    lo, hi = np.log(LO), np.log(HI)
    rng = np.random.default_rng(args.seed)
    report = {"set": args.set, "structures": {}}
    for structure in args.structures:
        def residuals(u):
            p = np.exp(lo + u * (hi - lo))
            r = [np.where(pv.mask, trace(p, structure, pv, soc0) - np.nan_to_num(pv.target), 0.0)
                 for pv, soc0 in zip(train, train_starts)]
            return np.nan_to_num(np.concatenate(r), nan=10.0, posinf=10.0, neginf=-10.0)

        runs = []
        for s in range(args.starts):
            fit = least_squares(residuals, rng.uniform(0.05, 0.95, len(NAMES)), bounds=(0.0, 1.0), method="trf",
                                max_nfev=args.max_nfev, diff_step=1e-4)
            p = np.exp(lo + fit.x * (hi - lo))
            run = {"start": s, "train_rmse_mv": round(1e3 * math.sqrt(2 * fit.cost / fit.fun.size), 1),
                   "parameters": {n: float(f"{v:.5g}") for n, v in zip(NAMES, p)}, "flights": {}}
            for name, (e, pv) in flights.items():
                if e["split"] == "train":
                    continue
                run["flights"][name] = {
                    "split": e["split"], "cutoff": e["reached_cutoff"],
                    **{f"{label}_mv": round(1e3 * rmse(trace(p, structure, pv, soc0), pv), 1) for label, soc0 in
                       (("rest10", rest_soc(pv, False)), ("rest_all", rest_soc(pv, True)),
                        ("true_start", e["initial_soc"]))}}
            runs.append(run)
            print(f"{args.set} {structure} start {s}: train {run['train_rmse_mv']} mV; "
                  + "; ".join(f"{n} {f['rest10_mv']}/{f['rest_all_mv']}/{f['true_start_mv']}"
                              for n, f in run["flights"].items()), flush=True)
        report["structures"][structure] = runs
    report["start_readings"] = {n: {"true": e["initial_soc"], "rest10": round(rest_soc(pv, False), 4),
                                    "rest_all": round(rest_soc(pv, True), 4)} for n, (e, pv) in flights.items()}
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
