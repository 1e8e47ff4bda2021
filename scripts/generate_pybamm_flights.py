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

Experiment (off by default, so the committed fixtures stay reproducible): ``--train-rests N`` gives
the training flights N rests each (``--rest-s`` long, inserted in the cruise, the flight
longer by as much), placed where the planned charge count reaches SoCs spread evenly over
``--rest-soc-range`` across all training flights, so the
open-circuit voltage is pinned across the SoC range and not only at the flights' starts. Every flight
is first simulated exactly as without the option (same random draws, same splits, so the same
validation and test flights; PyBaMM's solver on another machine may move a voltage by < 1 mV), then the training flights are simulated again with the rests
(their noise from a separate seeded stream) and replace the plain ones; the manifest lists each
training flight's rests. ``--train-start-socs LO HI`` (also off by default) instead re-flies the
training flights from initial SoCs spread evenly over [LO, HI], so their starting rests cover that
range evenly. docs/fitting.md ("Independent data") has what it showed.

Output: ``<set>/<flight>.parquet`` (columns of gcs_pdm.logs.tables: time_s, current_a, voltage_v,
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
#: another of PyBaMM's parameter sets (``--sets``, an experiment: a check on cells no fit was tuned on)
#: cruises at Chen2020's modest rates unless listed above
DEFAULT_C_RATES = C_RATES["Chen2020"]
DEFAULT_BURST_CAP = BURST_CAP["Chen2020"]
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


def window_capacity_ah(pv) -> float:
    """The charge between the set's 0 % and 100 % stoichiometries (what ``set_initial_state``'s SoC
    is a fraction of), Ah: the negative electrode's lithium over that window. Not the nominal
    capacity: Marquis2019's window holds 0.873 Ah where its nominal is 0.681 (Chen2020 5.15 / 5.0)."""
    import pybamm

    x_0, x_100 = pybamm.lithium_ion.get_min_max_stoichiometries(pv)[:2]
    area = pv["Electrode width [m]"] * pv["Electrode height [m]"]
    area *= pv.get("Number of electrodes connected in parallel to make a cell", 1)
    lithium = (pv["Negative electrode active material volume fraction"]
               * pv["Maximum concentration in negative electrode [mol.m-3]"] * pv["Negative electrode thickness [m]"])
    return float(abs(x_100 - x_0) * lithium * area * 96485.33212 / 3600.0)


#: the set whose values fill what another set does not publish (Prada2013's A123 LFP cell has no current
#: collector thickness, Ramadass2004's Sony cell no cell volume; the lumped thermal model needs both)
THERMAL_DEFAULTS_SET = "Chen2020"


def with_thermal_defaults(pybamm, pv):
    """``pv`` with every parameter it lacks taken from ``THERMAL_DEFAULTS_SET`` (current collectors, cell
    volume, cooling, heat capacities): what ``pv`` publishes, its electrodes, windows and curves, is
    untouched, and a parameter the model does not use changes nothing."""
    have = set(pv.keys())
    missing = {k: v for k, v in pybamm.ParameterValues(THERMAL_DEFAULTS_SET).items() if k not in have}
    if missing:
        pv.update(missing, check_already_exists=False)
    return pv


def simulate_cell(pybamm, set_name: str, t: np.ndarray, cell_current: np.ndarray, ambient_k: float, soc0: float):
    model = pybamm.lithium_ion.SPMe(options={"thermal": "lumped"})
    pv = with_thermal_defaults(pybamm, pybamm.ParameterValues(set_name))
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


def planned_soc(current_a: np.ndarray, soc0: float) -> np.ndarray:
    """SoC at the start of each 1 s sample by the charge count on the nominal pack capacity."""
    return soc0 - np.concatenate([[0.0], np.cumsum(current_a)[:-1]]) / (PACK_CAPACITY_AH * 3600.0)


def cruise_span(current_a: np.ndarray) -> tuple[int, int]:
    """(first, last + 1) sample of the profile's flight (non-zero current): rests are put inside it."""
    on = np.flatnonzero(current_a > 0)
    return int(on[0]), int(on[-1]) + 1


def plan_rests(plans: list[dict], per_flight: int, rest_s: int, soc_range: tuple[float, float]) -> dict[str, list[int]]:
    """Sample indices (in each plain profile) where each training flight rests: SoC targets spread
    evenly over ``soc_range`` (per_flight x flights of them), each given to a flight that passes it
    in its cruise (after the climb, until 120 s before the descent or the plain flight's cut-off) and
    has the fewest rests so far. A target no flight passes is left out (the manifest lists the rests
    placed). Never before take-off: PyBaMM 26.10's IDAKLU solve of a flight that opens with a 30 min
    rest came out wrong for 7 of 16 training flights (no heating, volts off, no cut-off), while
    flights with rests in the cruise match the plain ones to the noise outside the rests."""
    n = per_flight * len(plans)
    targets = np.linspace(soc_range[1], soc_range[0], n)
    windows = {}
    for p in plans:
        cur = p["current"]
        a, c = cruise_span(cur)
        climb_end = a + int(np.argmax(cur[a:] < cur[a] - 1e-9))
        descent = c - int(np.argmax(cur[:c][::-1] > cur[c - 1] + 1e-9))   # the throttled-back descent
        end = min(p["samples"], descent) - 120
        soc = planned_soc(p["current"], p["soc0"])
        windows[p["name"]] = (climb_end, end, soc)
    chosen: dict[str, list[int]] = {p["name"]: [] for p in plans}
    for target in targets:
        ok = []
        for name, (lo, hi, soc) in windows.items():
            if hi <= lo or len(chosen[name]) >= per_flight:
                continue
            if soc[hi] <= target <= soc[lo]:
                k = lo + int(np.argmax(soc[lo:hi + 1] <= target))
                if all(abs(k - j) > 120 for j in chosen[name]):  # two rests of one flight 2 min of flight apart
                    ok.append((len(chosen[name]), name, k))
        if ok:
            _, name, k = min(ok)
            chosen[name].append(k)
    return {name: sorted(ks) for name, ks in chosen.items()}


def with_rests(current_a: np.ndarray, at: list[int], rest_s: int) -> np.ndarray:
    """The profile with a rest of ``rest_s`` inserted at each index in ``at`` (longer by as much: the
    loaded part is the plain flight's, sample for sample)."""
    parts, last = [], 0
    for k in sorted(at):
        parts += [current_a[last:k], np.zeros(rest_s)]
        last = k
    return np.concatenate(parts + [current_a[last:]])


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
    ap.add_argument("--sets", nargs="+", default=list(SETS), metavar="SET",
                    help="PyBaMM parameter sets to fly (default: the committed fixtures' two; another set is an "
                         "experiment, its random draws are those of the first set's position)")
    ap.add_argument("--train-rests", type=int, default=0, metavar="N",
                    help="experiment: N relaxed rests per training flight (default 0: the committed fixtures)")
    ap.add_argument("--rest-s", type=int, default=600, help="length of each such rest, s")
    ap.add_argument("--rest-soc-range", type=float, nargs=2, default=(0.5, 0.95), metavar=("LO", "HI"),
                    help="planned SoCs of the rests, spread evenly over this range")
    ap.add_argument("--train-start-socs", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                    help="experiment: the training flights start at SoCs spread evenly over this range (in the "
                         "order of their drawn ones) instead of the drawn ones (default: drawn, as committed)")
    ap.add_argument("--rest-around-s", type=int, nargs=2, default=(0, 0), metavar=("BEFORE", "AFTER"),
                    help="experiment: each flight's drawn profile with this much more rest before take-off and "
                         "after landing (s), the rests a health point's capacity needs (packs/health.py: 60 s "
                         "and 600 s); the noise of a padded record is drawn from a stream of its own, so the "
                         "flights after it differ from the committed ones (default 0 0: as committed)")
    ap.add_argument("--ageing", action="store_true",
                    help="instead: one ageing cell per set (--ageing-sets), flown from cycle 1 to --cycles with its "
                         "true C/20 capacity at each flight (fixtures/pybamm_ageing; see AGEING_SETS)")
    ap.add_argument("--cycles", type=int, default=44,
                    help="with --ageing: flights (cycles) per ageing set, unless AGEING_SETS gives its own")
    ap.add_argument("--ageing-sets", nargs="+", default=list(AGEING_SETS), metavar="SET")
    args = ap.parse_args(argv)
    if args.ageing:
        return ageing_main(args)

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
    for position, set_name in enumerate(args.sets):
        (out / set_name).mkdir(parents=True, exist_ok=True)
        cell_ah = float(pybamm.ParameterValues(set_name)["Nominal cell capacity [A.h]"])
        parallel = PACK_CAPACITY_AH / cell_ah
        manifest["sets"][set_name] = {"cell_capacity_ah": cell_ah, "cells_parallel": parallel,
                                      "cell_window_capacity_ah": window_capacity_ah(pybamm.ParameterValues(set_name))}
        n = args.flights
        # spread the conditions over the flights, then shuffle which flight lands in which split
        ambients = np.linspace(0.0, 35.0, n)
        c_rates = np.tile(C_RATES.get(set_name, DEFAULT_C_RATES), n // 6 + 1)[:n]
        rng.shuffle(c_rates)
        rng.shuffle(ambients)
        plans = []
        for k in range(n):
            name = f"{set_name.lower()}_{k + 1:02d}"
            ambient = float(ambients[k] + rng.uniform(-1.0, 1.0)).__round__(2)
            ambient = min(max(ambient, 0.0), 35.0)
            c_rate = float(c_rates[k])
            soc0 = float(rng.uniform(0.75, 1.0))
            pack_i = flight_profile(rng, c_rate, args.duration, BURST_CAP.get(set_name, DEFAULT_BURST_CAP))
            padded = any(args.rest_around_s)
            if padded:  # longer rests around the same flight (--rest-around-s)
                pack_i = np.concatenate([np.zeros(args.rest_around_s[0]), pack_i, np.zeros(args.rest_around_s[1])])
            t = np.arange(0.0, float(pack_i.size))
            t0 = time.perf_counter()
            try:
                ts, v_cell, temp, v_cut, _ = simulate_cell(pybamm, set_name, t, pack_i / parallel, ambient + 273.15,
                                                           soc0)
            except pybamm.SolverError as exc:  # e.g. a start above the set's upper voltage at this ambient
                print(f"{name}: not simulated: {exc}", flush=True)
                continue
            m = ts.size
            cutoff = m < t.size - 1
            cols = {"time_s": ts, "current_a": pack_i[:m], "voltage_v": CELLS_SERIES * v_cell,
                    "temperature_c": temp, "ambient_c": np.full(m, ambient)}
            # a padded record's noise: a stream of its own (--rest-around-s)
            noisy = add_sensor_effects(np.random.default_rng([args.seed, 2000 + position, k]) if padded else rng, cols)
            pd.DataFrame(noisy).astype("float32").to_parquet(out / set_name / f"{name}.parquet", index=False)
            manifest["flights"].append({"flight": name, "set": set_name, "file": f"{set_name}/{name}.parquet",
                                        "ambient_c": ambient, "cruise_c_rate": c_rate,
                                        "initial_soc": round(soc0, 4), "samples": int(m), "reached_cutoff": bool(cutoff),
                                        "cell_cutoff_v": v_cut, "seconds_to_simulate": round(time.perf_counter() - t0, 2)})
            print(f"{name}: {ambient:5.1f} C  {c_rate:.1f}C  SoC0 {soc0:.2f}  {m} s"
                  f"{'  cut-off' if cutoff else ''}", flush=True)
            plans.append({"name": name, "t": t, "current": pack_i, "ambient": ambient, "soc0": soc0, "samples": m})
        split_rng = np.random.default_rng([args.seed, position])
        assign_splits([f for f in manifest["flights"] if f["set"] == set_name], split_rng)
        if args.train_rests > 0 or args.train_start_socs is not None:
            # the experiment: the training flights again, with rests (docstring); a stream of their own,
            # so nothing above changes
            entries = {f["flight"]: f for f in manifest["flights"] if f["set"] == set_name}
            train = [p for p in plans if entries[p["name"]]["split"] == "train"]
            if args.train_start_socs is not None:
                spread = np.linspace(*args.train_start_socs, len(train))
                for rank, j in enumerate(np.argsort([p["soc0"] for p in train], kind="stable")):
                    train[j]["soc0"] = float(spread[rank])
                    entries[train[j]["name"]]["initial_soc"] = round(float(spread[rank]), 4)
            at = (plan_rests(train, args.train_rests, args.rest_s, tuple(args.rest_soc_range)) if args.train_rests > 0
                  else {p["name"]: [] for p in train})
            rest_rng = np.random.default_rng([args.seed, 1000 + position])
            for p in train:
                pack_i = with_rests(p["current"], at[p["name"]], args.rest_s)
                t_long = np.arange(0.0, float(pack_i.size))
                t0 = time.perf_counter()
                ts, v_cell, temp, _, _ = simulate_cell(pybamm, set_name, t_long, pack_i / parallel,
                                                       p["ambient"] + 273.15, p["soc0"])
                m = ts.size
                cols = {"time_s": ts, "current_a": pack_i[:m], "voltage_v": CELLS_SERIES * v_cell,
                        "temperature_c": temp, "ambient_c": np.full(m, p["ambient"])}
                pd.DataFrame(add_sensor_effects(rest_rng, cols)).astype("float32").to_parquet(
                    out / set_name / f"{p['name']}.parquet", index=False)
                soc = planned_soc(p["current"], p["soc0"])
                shifted = [k + j * args.rest_s for j, k in enumerate(at[p["name"]])]
                entries[p["name"]].update(samples=int(m), reached_cutoff=bool(m < t_long.size - 1),
                                          seconds_to_simulate=round(time.perf_counter() - t0, 2),
                                          rests=[{"start_s": k, "seconds": args.rest_s,
                                                  "planned_soc": round(float(soc[k0]), 4)}
                                                 for k, k0 in zip(shifted, at[p["name"]]) if k < m])
                placed = ", ".join(f"{r['planned_soc']:.2f}" for r in entries[p["name"]]["rests"]) or "none"
                print(f"{p['name']} again from SoC {p['soc0']:.2f}, rests at SoC {placed}: {m} s"
                      f"{'  cut-off' if m < t_long.size - 1 else ''}", flush=True)
            manifest["train_rests"] = {"per_flight": args.train_rests, "seconds": args.rest_s,
                                       "soc_range": list(args.rest_soc_range)}
            if args.train_start_socs is not None:
                manifest["train_start_socs"] = list(args.train_start_socs)
    if any(args.rest_around_s):
        manifest["rest_around_s"] = {"before": args.rest_around_s[0], "after": args.rest_around_s[1]}
    manifest["seconds"] = round(time.perf_counter() - t_all, 1)
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return 0


# --- ageing: one cell from its first flight to past end of life ----------------------------------------

#: PyBaMM parameter set -> its degradation submodels and the factor on the rate that sets how fast the
#: cell ages (accelerated so a cell reaches 80 % capacity in tens of flights, not the ~1000 cycles of
#: its published rate: the wear mechanism is the model's, the calendar is compressed)
AGEING_SETS = {
    # O'Kane et al. 2022 (LG M50): solvent-diffusion-limited SEI growth and irreversible lithium plating
    "OKane2022": {"options": {"SEI": "solvent-diffusion limited", "lithium plating": "irreversible"},
                  "accelerate": {"Lithium plating kinetic rate constant [m.s-1]": 0.3},
                  "cruise_c": (1.2, 1.8), "charge_c": 0.5},
    # Chen et al. 2020 (LG M50): solvent-diffusion-limited SEI growth only
    "Chen2020": {"options": {"SEI": "solvent-diffusion limited"},
                 "accelerate": {"SEI solvent diffusivity [m2.s-1]": 8000.0, "SEI resistivity [Ohm.m]": 3.0},
                 "cruise_c": (1.2, 1.8), "charge_c": 1.0, "cycles": 64},
}
#: the wear reactions' rates, held still (x WEAR_FROZEN) while the true capacity is measured: the
#: fixtures wear in tens of cycles where a real LG M50 takes ~1000, and at those rates a 20-h C/20
#: discharge loses lithium during the measurement itself: 6 % of the fresh Chen2020 cell (its SEI
#: x8000), 1.4 % of O'Kane2022's (its plating, which PyBaMM's irreversible model runs even at +90 mV
#: against lithium). A capacity test on a real cell sees neither (docs/notes/2026-11-27-pack-capacity.md)
WEAR_RATES = ("SEI solvent diffusivity [m2.s-1]", "Lithium plating kinetic rate constant [m.s-1]")
WEAR_FROZEN = 1e-6
#: the planned depth of discharge of a fresh cell's flight (deeper as it ages: the profile is fixed)
AGEING_FLIGHT_DOD = 0.6
#: rests: before the flight (after the CC-CV charge) and after landing, long enough to relax
AGEING_REST_BEFORE_S, AGEING_REST_AFTER_S = 1800, 3600
#: cell sensor noise (a 5S pack's 10 mV is ~2 mV per cell), current noise
AGEING_NOISE_V, AGEING_NOISE_A = 0.002, 0.01


def ageing_profile(rng: np.random.Generator, cap_ah: float, c_lo: float, c_hi: float) -> np.ndarray:
    """Cell current (A) at 1 Hz for one flight: climb, cruise with gusts and bursts, descent; its
    length gives a fresh cell ``AGEING_FLIGHT_DOD``."""
    cruise_c = float(rng.uniform(c_lo, c_hi))
    n = int(AGEING_FLIGHT_DOD * 3600.0 / cruise_c)
    i = flight_profile(rng, cruise_c, n + 2, burst_cap=2.2)[1:-1]   # the pack profile, no rests
    i = i / PACK_CAPACITY_AH * cap_ah
    i[i <= 0] = 0.05 * cruise_c * cap_ah                               # props idle on the ground roll
    return i


#: the take-off step, as the health point reads it (gcs_pdm/packs/health.py): the flight's first current
#: step of at least this share of 1C between two samples, within TAKEOFF_WINDOW_S of its first load
TAKEOFF_STEP_C, TAKEOFF_WINDOW_S = 0.2, 120.0


def takeoff_step_resistance(t: np.ndarray, i: np.ndarray, v: np.ndarray, first: int, cap_ah: float) -> float | None:
    """The noiseless 1-s resistance at the take-off step (idle to climb, ~2C on these flights): the
    quantity the health point reads, where ``true_pulse_resistance_ohm`` is the small-signal one at
    the rest-to-idle step (~0.08C). Butler-Volmer kinetics make the two differ by up to 3x and move
    differently as the electrodes' windows shift (docs/notes/2026-11-27-pack-capacity-rests.md)."""
    di = np.diff(i[first:])
    near = t[first:-1] - t[first] <= TAKEOFF_WINDOW_S
    steps = np.flatnonzero((np.abs(di) >= TAKEOFF_STEP_C * cap_ah) & near)
    if steps.size == 0:
        return None
    k = first + int(steps[0])
    return float((v[k] - v[k + 1]) / (i[k + 1] - i[k]))


def fresh_electrodes(pybamm, pv) -> dict:
    """The fresh cell's electrodes (what a chemistry's datasheet-level model gives): each electrode's
    potential on a stoichiometry grid at 25 °C, their capacities (Ah) and the cell's stoichiometry
    windows; a capacity estimate that reads lithium loss needs them (docs/packs.md)."""
    def electrode_potential(pybamm, values, name, sto):
        fn = values[name]
        try:
            expr = fn(pybamm.Scalar(sto))
        except TypeError:  # parameter sets whose potentials take the temperature too
            expr = fn(pybamm.Scalar(sto), pybamm.Scalar(298.15))
        return float(np.asarray(values.evaluate(expr)).ravel()[0])

    grid = np.round(np.linspace(0.001, 0.999, 333), 6)
    param = pybamm.LithiumIonParameters()
    x_0, x_100, y_100, y_0 = pybamm.lithium_ion.get_min_max_stoichiometries(pv)
    return {"stoichiometry": grid.tolist(),
            "negative_v": [round(electrode_potential(pybamm, pv, "Negative electrode OCP [V]", x), 6) for x in grid],
            "positive_v": [round(electrode_potential(pybamm, pv, "Positive electrode OCP [V]", y), 6) for y in grid],
            "negative_ah": float(pv.evaluate(param.n.Q_init)), "positive_ah": float(pv.evaluate(param.p.Q_init)),
            "x_0": float(x_0), "x_100": float(x_100), "y_0": float(y_0), "y_100": float(y_100)}


def ageing_main(args) -> int:
    """``--ageing``: per set, one cell flown ``--cycles`` times; each cycle a CC-CV charge, a rest, one
    flight, a rest. Each flight's log (the last 2 min of the rest before it, the flight, the rest after:
    1 Hz for a minute, then every 30 s) is ``<set>/<set>_NNN.parquet`` (cell current, voltage,
    temperature, ambient); the manifest has, per flight, the cell's true capacity (a C/20 discharge
    from the charged, rested state, on a copy of the cell with its wear held still, WEAR_RATES: the
    cell itself never sees it) and its true pulse resistances (the noiseless 1-s voltage step over the
    rest-to-idle current step that opens the flight, and over the take-off step:
    ``takeoff_step_resistance``), and per set the
    fresh cell's open-circuit voltage curve along that C/20 discharge."""
    import pandas as pd
    import pybamm

    out = Path(args.out)
    rng = np.random.default_rng(args.seed)
    manifest = {"generator": "scripts/generate_pybamm_flights.py --ageing", "pybamm": pybamm.__version__,
                "seed": args.seed, "model": "SPM, isothermal 25 C, degradation submodels per set",
                "columns": ["time_s", "current_a", "voltage_v", "temperature_c", "ambient_c"],
                "noise": {"voltage_v": AGEING_NOISE_V, "current_a": AGEING_NOISE_A},
                "rests_s": {"before": AGEING_REST_BEFORE_S, "after": AGEING_REST_AFTER_S},
                "sets": {}, "flights": []}
    t_all = time.perf_counter()
    for set_name in args.ageing_sets:
        rng = np.random.default_rng(args.seed)  # each set its own stream: a set is remade alone, the same
        spec = AGEING_SETS[set_name]
        pv = pybamm.ParameterValues(set_name)
        pv.update({k: pv[k] * f for k, f in spec["accelerate"].items()})
        pv.update({"Ambient temperature [K]": 298.15, "Initial temperature [K]": 298.15})
        pv_measure = pv.copy()
        frozen = [k for k in WEAR_RATES if k in pv.keys()]
        pv_measure.update({k: pv[k] * WEAR_FROZEN for k in frozen})
        model = pybamm.lithium_ion.SPM(options=spec["options"])
        electrodes = fresh_electrodes(pybamm, pv)
        cap = float(pv["Nominal cell capacity [A.h]"])
        vmax, vmin = float(pv["Upper voltage cut-off [V]"]), float(pv["Lower voltage cut-off [V]"])
        profiles = [ageing_profile(rng, cap, *spec["cruise_c"]) for _ in range(spec.get("cycles", args.cycles))]
        steps = []
        for prof in profiles:
            drive = pybamm.step.current(np.column_stack([np.arange(prof.size, dtype=float), prof]))
            steps.append((f"Charge at {spec['charge_c']}C until {vmax} V", f"Hold at {vmax} V until C/50",
                          f"Rest for {AGEING_REST_BEFORE_S} seconds", drive, f"Rest for {AGEING_REST_AFTER_S} seconds"))
        t0 = time.perf_counter()
        sim = pybamm.Simulation(model, parameter_values=pv, experiment=pybamm.Experiment(steps),
                                solver=pybamm.IDAKLUSolver())
        sol = sim.solve(initial_soc=1.0)
        print(f"{set_name}: {len(sol.cycles)} cycles simulated in {time.perf_counter() - t0:.0f} s", flush=True)
        (out / set_name).mkdir(parents=True, exist_ok=True)
        set_entry = {"options": spec["options"], "accelerate": spec["accelerate"], "nominal_cell_capacity_ah": cap,
                     "upper_cutoff_v": vmax, "lower_cutoff_v": vmin, "cycles": len(sol.cycles),
                     "truth_with_wear_frozen": {k: WEAR_FROZEN for k in frozen},
                     "electrodes": electrodes}
        for k, cycle in enumerate(sol.cycles):
            if len(cycle.steps) < 5:  # the experiment stopped in this cycle (a step hit a voltage limit)
                print(f"{set_name}: cycle {k + 1} incomplete, the cell's life ends there", flush=True)
                break
            rested = cycle.steps[2]
            # truth: a C/20 discharge from the charged, rested state, on a copy of the cell
            # with the wear reactions held still (WEAR_RATES above); the capacity with them running
            # as in the flights is kept beside it for the record
            truth_model = model.set_initial_conditions_from(rested, inplace=False)
            c20 = pybamm.Simulation(truth_model, parameter_values=pv_measure,
                                    experiment=pybamm.Experiment([f"Discharge at C/20 until {vmin} V"]),
                                    solver=pybamm.IDAKLUSolver()).solve()
            q = c20["Discharge capacity [A.h]"].entries
            true_ah = float(q[-1] - q[0])
            c20_fast = pybamm.Simulation(model.set_initial_conditions_from(rested, inplace=False), parameter_values=pv,
                                         experiment=pybamm.Experiment([f"Discharge at C/20 until {vmin} V"]),
                                         solver=pybamm.IDAKLUSolver()).solve()
            q_fast = c20_fast["Discharge capacity [A.h]"].entries
            stoich = [float(rested[f"Average {e} particle stoichiometry"].entries[-1]) for e in ("negative", "positive")]
            after_rest = cycle.steps[4]
            lost_in_flight = float(sum(
                (rested[f"Average {e} particle stoichiometry"].entries[-1]
                 - after_rest[f"Average {e} particle stoichiometry"].entries[-1]) * q_e
                for e, q_e in (("negative", electrodes["negative_ah"]), ("positive", electrodes["positive_ah"]))))
            if k == 0:
                ocv = c20["Battery open-circuit voltage [V]"].entries
                frac = (q - q[0]) / true_ah
                pick = np.linspace(0, frac.size - 1, 201).astype(int)
                set_entry["ocv_curve"] = {"soc": [round(1.0 - float(x), 5) for x in frac[pick]],
                                          "voltage_v": [round(float(v), 5) for v in ocv[pick]]}
            parts = [cycle.steps[2], cycle.steps[3], cycle.steps[4]]
            ts = np.concatenate([p["Time [s]"].entries for p in parts])
            vs = np.concatenate([p["Voltage [V]"].entries for p in parts])
            cs = np.concatenate([p["Current [A]"].entries for p in parts])
            flight_start = float(parts[1]["Time [s]"].entries[0])
            rest_end = float(parts[2]["Time [s]"].entries[-1])
            after = float(parts[2]["Time [s]"].entries[0])
            grid = np.concatenate([np.arange(flight_start - 120.0, after + 60.0, 1.0),
                                   np.arange(after + 90.0, rest_end - 1e-6, 30.0), [rest_end]])
            order = np.argsort(ts, kind="stable")
            ts, vs, cs = ts[order], vs[order], cs[order]
            keep = np.concatenate([[True], np.diff(ts) > 1e-9])
            ts, vs, cs = ts[keep], vs[keep], cs[keep]
            v = np.interp(grid, ts, vs)
            # a logger samples both at one instant: at a step's instant the solution holds the step
            # before it (voltage and current alike), so the current is taken just before the instant too
            i = np.interp(grid - 1e-3, ts, cs)
            j = int(np.searchsorted(grid, flight_start))
            # 1 s after the step, as a 1 Hz log sees it
            true_r = float((v[j - 1] - v[j + 1]) / (i[j + 1] - i[j - 1])) if abs(i[j + 1] - i[j - 1]) > 1e-6 else None
            true_r_takeoff = takeoff_step_resistance(grid, i, v, j, cap)
            n = grid.size
            cols = {"time_s": grid - grid[0], "current_a": i + rng.normal(0, AGEING_NOISE_A, n),
                    "voltage_v": v + rng.normal(0, AGEING_NOISE_V, n),
                    "temperature_c": np.round((25.0 + rng.normal(0, 0.1, n)) * 10.0) / 10.0,
                    "ambient_c": np.full(n, 25.0)}
            name = f"{set_name.lower()}_{k + 1:03d}"
            pd.DataFrame(cols).astype({"time_s": "float64", "current_a": "float32", "voltage_v": "float32",
                                       "temperature_c": "float32", "ambient_c": "float32"}).to_parquet(
                out / set_name / f"{name}.parquet", index=False)
            drawn = float(np.sum(profiles[k])) / 3600.0
            manifest["flights"].append({"flight": name, "set": set_name, "cycle": k + 1,
                                        "file": f"{set_name}/{name}.parquet", "true_capacity_ah": round(true_ah, 6),
                                        "c20_capacity_wear_running_ah": round(float(q_fast[-1] - q_fast[0]), 6),
                                        "true_stoichiometry_rested": [round(x, 6) for x in stoich],
                                        "lithium_lost_flight_and_rest_ah": round(lost_in_flight, 6),
                                        "true_pulse_resistance_ohm": None if true_r is None else round(true_r, 7),
                                        "true_takeoff_resistance_ohm": (None if true_r_takeoff is None
                                                                        else round(true_r_takeoff, 7)),
                                        "drawn_ah": round(drawn, 5), "flight_s": int(profiles[k].size),
                                        "samples": int(n)})
            print(f"{name}: true C/20 capacity {true_ah:.4f} Ah, pulse R {true_r * 1e3:.2f} mOhm", flush=True)
        manifest["sets"][set_name] = set_entry
    manifest["seconds"] = round(time.perf_counter() - t_all, 1)
    out.mkdir(parents=True, exist_ok=True)
    previous = out / "manifest.json"
    if previous.exists():  # the sets not made in this run stay as they were
        old = json.loads(previous.read_text())
        for name, entry in old.get("sets", {}).items():
            if name not in manifest["sets"]:
                manifest["sets"][name] = entry
                manifest["flights"] += [f for f in old["flights"] if f["set"] == name]
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
