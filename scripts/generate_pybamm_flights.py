"""Independent test flights: a 5S pack simulated by PyBaMM's SPMe with a lumped thermal model.

Development tool, not part of the product: it needs the ``fixtures`` extra (PyBaMM), which is kept out
of the shared environment (it pins its own numpy/casadi). Run it in its own venv:

    python -m venv /work/venv-pybamm && /work/venv-pybamm/bin/pip install pybamm pandas pyarrow
    /work/venv-pybamm/bin/python scripts/generate_pybamm_flights.py --out fixtures/pybamm

For each parameter set (Chen2020: LG M50 21700 NMC811/graphite-SiOx; Marquis2019: Kokam NMC/graphite
pouch) it flies ``--flights`` flight-like current profiles: a rest before arming (for the initial
SoC), a take-off climb, a cruise between 1C and 4C with turns and climb bursts, a descent and a rest
after landing; ambient between 0 and 35 °C; initial SoC between 0.75 and 1; some flights run to the
cut-off (the simulation stops at the cell's lower voltage limit). Five cells in series, enough in
parallel for ~7.8 Ah: the pack current is divided by the cells in parallel, the voltage multiplied by
five; the pack temperature is the cell's volume-averaged temperature. Sensor noise (voltage 10 mV,
current 0.05 A, temperature 0.1 K quantised to 0.1 K, ambient 0.2 K) and drop-outs (runs of missing
voltage/temperature samples) are added after the simulation. Everything is seeded.

Output: ``<set>/<flight>.parquet`` (columns of gcs_pdm.fitting.tables: time_s, current_a, voltage_v,
temperature_c, ambient_c at 1 Hz) and ``manifest.json`` (per flight: set, split, ambient, C-rate,
initial SoC, whether it reached the cut-off; per set: cells in parallel, capacity).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

PACK_CAPACITY_AH = 7.8
CELLS_SERIES = 5
SETS = ("Chen2020", "Marquis2019")
#: cruise C-rates (of the 7.8 Ah pack) per set: the LG M50 energy cell of Chen2020 is rated 1.5C
#: continuous, and SPMe runs out of electrolyte above ~2.5C on it, so its flights cruise at 1-2C;
#: the Kokam pouch of Marquis2019 cruises at 1-3C and climbs at up to 4C. Above that the SPMe itself
#: leaves the DFN model it approximates (Marquis et al. 2019 validate it to a few C), so flights there
#: would test PyBaMM's reduction, not our circuit.
C_RATES = {"Chen2020": (1.0, 1.2, 1.4, 1.6, 1.8, 2.0), "Marquis2019": (1.0, 1.4, 1.8, 2.2, 2.6, 3.0)}
#: highest C-rate of a climb burst per set
BURST_CAP = {"Chen2020": 2.2, "Marquis2019": 4.0}
#: per parameter set: 2 validation and 2 test flights, the rest train
N_VALIDATION = N_TEST = 2


def assign_splits(flights: list[dict], rng: np.random.Generator) -> None:
    """Stratified, before any fit: validation and test each get one flight that reached the cut-off
    and one that did not (when there are such flights), so every split covers the end-of-discharge
    knee and a plain cruise; the rest train."""
    cut = [f for f in flights if f["reached_cutoff"]]
    full = [f for f in flights if not f["reached_cutoff"]]
    rng.shuffle(cut)
    rng.shuffle(full)
    for split, n in (("test", N_TEST), ("validation", N_VALIDATION)):
        for k in range(n):
            first, other = (cut, full) if k % 2 == 0 else (full, cut)
            (first or other).pop()["split"] = split
    for f in flights:
        f.setdefault("split", "train")


def flight_profile(rng: np.random.Generator, c_rate: float, duration_s: int, burst_cap: float) -> np.ndarray:
    """Pack current (A) at 1 Hz: rest, take-off climb, cruise with turns and climb bursts, descent, rest."""
    cruise = c_rate * PACK_CAPACITY_AH
    n = duration_s
    i = np.zeros(n)
    rest0 = int(rng.integers(30, 60))
    climb = int(rng.integers(60, 120))
    descent = int(rng.integers(60, 120))
    rest1 = int(rng.integers(30, 60))
    cap = max(burst_cap * PACK_CAPACITY_AH, cruise)
    a, b = rest0, rest0 + climb
    i[a:b] = min(cruise * rng.uniform(1.3, 1.6), cap)
    c = n - rest1 - descent
    t = np.arange(b, c)
    # cruise: slow gusts and turns (a few % to 15 %) on the mean
    i[b:c] = cruise * (1.0 + 0.06 * np.sin(2 * np.pi * t / rng.uniform(60, 180) + rng.uniform(0, 6))
                       + 0.04 * np.sin(2 * np.pi * t / rng.uniform(15, 40)))
    for _ in range(int(rng.integers(2, 5))):           # climb bursts
        s = int(rng.integers(b, max(b + 1, c - 60)))
        i[s:s + int(rng.integers(20, 60))] = min(cruise * rng.uniform(1.2, 1.4), cap)
    i[c:n - rest1] = cruise * rng.uniform(0.3, 0.5)    # descent, throttled back
    i[:a] = 0.0
    i[n - rest1:] = 0.0
    return i


def simulate_cell(pybamm, set_name: str, t: np.ndarray, cell_current: np.ndarray, ambient_k: float, soc0: float):
    model = pybamm.lithium_ion.SPMe(options={"thermal": "lumped"})
    pv = pybamm.ParameterValues(set_name)
    pv.update({
        "Ambient temperature [K]": ambient_k,
        "Initial temperature [K]": ambient_k,
        "Current function [A]": pybamm.Interpolant(t, cell_current, pybamm.t, interpolator="linear"),
    })
    pv.set_initial_state(soc0)
    sim = pybamm.Simulation(model, parameter_values=pv, solver=pybamm.IDAKLUSolver())
    sol = sim.solve(t_eval=[float(t[0]), float(t[-1])], t_interp=t)
    ts = sol["Time [s]"].entries
    v = sol["Voltage [V]"].entries
    temp = sol["Volume-averaged cell temperature [K]"].entries - 273.15
    return ts, v, temp, float(pv["Lower voltage cut-off [V]"]), float(pv["Nominal cell capacity [A.h]"])


def add_sensor_effects(rng: np.random.Generator, cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    n = cols["time_s"].size
    out = dict(cols)
    out["voltage_v"] = cols["voltage_v"] + rng.normal(0, 0.010, n)
    out["current_a"] = cols["current_a"] + rng.normal(0, 0.05, n)
    out["temperature_c"] = np.round((cols["temperature_c"] + rng.normal(0, 0.1, n)) * 10.0) / 10.0
    out["ambient_c"] = cols["ambient_c"] + rng.normal(0, 0.2, n)
    for col in ("voltage_v", "temperature_c"):          # drop-outs: a few runs of missing samples
        for _ in range(int(rng.integers(1, 4))):
            s = int(rng.integers(60, max(61, n - 30)))
            out[col][s:s + int(rng.integers(3, 20))] = np.nan
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="fixtures/pybamm")
    ap.add_argument("--flights", type=int, default=12, help="flights per parameter set (12: 8 train, 2 val, 2 test)")
    ap.add_argument("--duration", type=int, default=1800, help="planned flight length, s (cut-off flights end early)")
    ap.add_argument("--seed", type=int, default=15)
    args = ap.parse_args(argv)

    import pandas as pd
    import pybamm

    out = Path(args.out)
    rng = np.random.default_rng(args.seed)
    manifest = {"generator": "scripts/generate_pybamm_flights.py", "pybamm": pybamm.__version__, "seed": args.seed,
                "model": "SPMe, lumped thermal", "pack": f"{CELLS_SERIES}S, ~{PACK_CAPACITY_AH} Ah",
                "columns": ["time_s", "current_a", "voltage_v", "temperature_c", "ambient_c"],
                "noise": {"voltage_v": 0.010, "current_a": 0.05, "temperature_c": "0.1 K, quantised 0.1 K",
                          "ambient_c": 0.2}, "sets": {}, "flights": []}
    t_all = time.perf_counter()
    for set_name in SETS:
        (out / set_name).mkdir(parents=True, exist_ok=True)
        cell_ah = float(pybamm.ParameterValues(set_name)["Nominal cell capacity [A.h]"])
        parallel = PACK_CAPACITY_AH / cell_ah
        manifest["sets"][set_name] = {"cell_capacity_ah": cell_ah, "cells_parallel": parallel}
        n = args.flights
        # spread the conditions over the flights, then shuffle which flight lands in which split
        ambients = np.linspace(0.0, 35.0, n)
        c_rates = np.tile(C_RATES[set_name], n // 6 + 1)[:n]
        rng.shuffle(c_rates)
        rng.shuffle(ambients)
        for k in range(n):
            name = f"{set_name.lower()}_{k + 1:02d}"
            ambient = float(ambients[k] + rng.uniform(-1.0, 1.0)).__round__(2)
            ambient = min(max(ambient, 0.0), 35.0)
            c_rate = float(c_rates[k])
            soc0 = float(rng.uniform(0.75, 1.0))
            t = np.arange(0.0, float(args.duration))
            pack_i = flight_profile(rng, c_rate, args.duration, BURST_CAP[set_name])
            t0 = time.perf_counter()
            ts, v_cell, temp, v_cut, _ = simulate_cell(pybamm, set_name, t, pack_i / parallel, ambient + 273.15, soc0)
            m = ts.size
            cutoff = m < t.size - 1
            cols = {"time_s": ts, "current_a": pack_i[:m], "voltage_v": CELLS_SERIES * v_cell,
                    "temperature_c": temp, "ambient_c": np.full(m, ambient)}
            noisy = add_sensor_effects(rng, cols)
            pd.DataFrame(noisy).astype("float32").to_parquet(out / set_name / f"{name}.parquet", index=False)
            manifest["flights"].append({"flight": name, "set": set_name, "file": f"{set_name}/{name}.parquet",
                                        "ambient_c": ambient, "cruise_c_rate": c_rate,
                                        "initial_soc": round(soc0, 4), "samples": int(m), "reached_cutoff": bool(cutoff),
                                        "cell_cutoff_v": v_cut, "seconds_to_simulate": round(time.perf_counter() - t0, 2)})
            print(f"{name}: {ambient:5.1f} C  {c_rate:.1f}C  SoC0 {soc0:.2f}  {m} s"
                  f"{'  cut-off' if cutoff else ''}", flush=True)
        split_rng = np.random.default_rng([args.seed, SETS.index(set_name)])
        assign_splits([f for f in manifest["flights"] if f["set"] == set_name], split_rng)
    manifest["seconds"] = round(time.perf_counter() - t_all, 1)
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
