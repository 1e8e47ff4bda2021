"""How well the self-calibrating estimator does (issue 29's harness; tests and
``benchmarks/bench_soc_calibration.py`` call these).

* ``real_log_soc``: a real autopilot's tlog replayed as ``gcs-pdm replay`` does without
  ``--vehicle`` (the provisional description, the diagnosis pipeline); at every pack frame the SoC
  against the autopilot's own charge count (``BATTERY_STATUS.battery_remaining``, carried beside the
  pack frame by an extra rule of the frame mapping, so both share the frame's message time).
* ``simulated_pack_soc``: a preset's pack flown by the kernel with its truth off the description
  (capacity, resistance, a partly charged start), with noise, through the estimator on the
  description; SoC against the truth.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcs_pdm.frames import PackFrame

#: the pack frames that carry the autopilot's count are named with this prefix
_COUNT_PREFIX = "autopilot-count:"


@dataclass
class PackTrack:
    """One pack's samples: message time, SoC, σ, and the reference (the autopilot's count or the truth)."""

    name: str
    time_s: np.ndarray
    soc: np.ndarray
    soc_sd: np.ndarray
    reference: np.ndarray

    def summary(self, after_s: float = 60.0) -> dict:
        t0 = self.time_s[0] if self.time_s.size else 0.0
        late = self.time_s >= t0 + after_s
        err = np.abs(self.soc - self.reference)[late]
        fin = np.isfinite(err)
        inside = np.abs(self.soc - self.reference)[late] <= 2.0 * self.soc_sd[late]
        known = self.reference[np.isfinite(self.reference)]
        return {"pack": self.name, "samples": int(late.sum()), "null_after_60s": int((~np.isfinite(self.soc[late])).sum()),
                "max_abs_error": round(float(err[fin].max()), 4) if fin.any() else None,
                "mean_abs_error": round(float(err[fin].mean()), 4) if fin.any() else None,
                "within_2sd": round(float(inside[fin].mean()), 3) if fin.any() else None,
                "reference_start": round(float(known[0]), 3) if known.size else None,
                "reference_end": round(float(known[-1]), 3) if known.size else None}


def real_log_soc(path: str | Path) -> tuple[dict, list[PackTrack]]:
    """(what the replay derived, one track per pack) for a tlog replayed without ``--vehicle``.
    A log from which no description is derived gives no tracks (``about["why"]`` says why)."""
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog
    from gcs_pdm.replay.vehicle import pipeline_for, replay_vehicle
    from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping

    path = Path(path)
    if path.suffix.lower() in (".bin", ".ulg"):
        return _autopilot_log_soc(path)
    desc, about = replay_vehicle(path, None)
    if desc is None:
        return about, []
    pipeline = pipeline_for(desc)
    est = pipeline.estimator
    mapping = frame_mapping(desc)
    rule = copy.deepcopy(mapping["BATTERY_STATUS"][0])
    rule["key"]["map"] = {k: _COUNT_PREFIX + v for k, v in rule["key"]["map"].items()}
    rule["fields"] = {"voltage_v": {"field": "battery_remaining", "scale": 0.01, "missing": [-1]},
                      "current_a": {"field": "current_consumed", "scale": 1.0, "missing": [-1]},
                      "temperature_c": {"field": "temperature", "scale": 0.01, "missing": [32767]}}
    mapping["BATTERY_STATUS"] = [*mapping["BATTERY_STATUS"], rule]
    mapper = FrameMapper(mapping, envelope=envelope(desc))
    count: dict[str, float] = {}
    rows: dict[str, list] = {n: [] for n in est.pack_names}

    def consume(frame) -> None:
        if isinstance(frame, PackFrame) and frame.pack.startswith(_COUNT_PREFIX):
            if frame.voltage_v is not None and math.isfinite(frame.voltage_v):
                count[frame.pack[len(_COUNT_PREFIX):]] = float(frame.voltage_v)
            return
        pipeline.consume(frame)
        if isinstance(frame, PackFrame) and frame.pack in rows:
            e = est.estimate(details=False)
            b = est.pack_names.index(frame.pack)
            rows[frame.pack].append((frame.time_s, e.soc[b], e.soc_sd[b], count.get(frame.pack, math.nan)))

    replay_tlog(path, mapper=mapper, frame_consumer=consume)
    tracks = [PackTrack(n, *(np.array(c, dtype=float) for c in zip(*r))) for n, r in rows.items() if r]
    return about, tracks


def _autopilot_log_soc(path: Path) -> tuple[dict, list[PackTrack]]:
    """``real_log_soc`` of an autopilot's own log (DataFlash, ULog): the description derived from it
    (``vehicle.from_log``), its battery instances mapped to the description's packs by instance, and
    the autopilot's count as 1 − consumed / the capacity parameter (the log carries no remaining %)."""
    from gcs_pdm.logs.reader import read_log
    from gcs_pdm.vehicle.description import VehicleError
    from gcs_pdm.logs.provisional_vehicle import observe_log
    from gcs_pdm.replay.vehicle import pipeline_for

    try:
        desc, notes = observe_log(path)
    except VehicleError as exc:
        return {"source": "none", "why": f"no description could be derived from the log: {exc}"}, []
    about = {"name": desc.name, "source": "provisional", "notes": notes}
    series = read_log(path)
    pipeline = pipeline_for(desc)
    est = pipeline.estimator
    frames = []
    for spec in desc.packs:
        b = series.batteries.get(spec.mavlink_battery_id)
        if b is None:
            continue
        capacity = spec.capacity_mah
        count = 1.0 - b.consumed_mah / capacity if capacity else np.full(b.time_s.size, np.nan)
        frames += [(float(t), spec.name, PackFrame(float(t), spec.name, _opt(v), _opt(i), _opt(c)), float(n))
                   for t, v, i, c, n in zip(b.time_s, b.voltage_v, b.current_a, b.temperature_c, count)]
    frames.sort(key=lambda r: r[0])
    rows: dict[str, list] = {n: [] for n in est.pack_names}
    for t, name, frame, counted in frames:
        pipeline.consume(frame)
        e = est.estimate(details=False)
        b = est.pack_names.index(name)
        rows[name].append((t, e.soc[b], e.soc_sd[b], counted))
    return about, [PackTrack(n, *(np.array(c, dtype=float) for c in zip(*r))) for n, r in rows.items() if r]


def _opt(v) -> float | None:
    return float(v) if v is not None and np.isfinite(v) else None


def simulated_pack_soc(preset: str, *, capacity_scale: float, resistance_scale: float, start_soc: float,
                       seed: int, duration_s: float = 900.0, rest_s: float = 30.0, dt: float = 1.0,
                       c_rate: tuple[float, float] = (0.5, 2.5), chemistry_curve: bool = False) -> PackTrack:
    """A preset's first pack, its truth off the description by ``capacity_scale`` and
    ``resistance_scale``, resting ``rest_s`` at ``start_soc`` then flying legs of 20-120 s at
    ``c_rate`` (of the description's capacity) until ``duration_s`` or cut-off; voltage noise 10 mV +
    2 mV per cell, current noise 1 %; through ``StateEstimator`` on the preset. SoC against the
    truth's (the fraction of the true capacity left).

    ``chemistry_curve``: the truth rests on its chemistry's curve (``sim.pack_curves``) and the
    estimator is told only what a derived description says (the preset marked provisional: the
    chemistry table's prior, as for a vehicle the service was never told about)."""
    case = simulated_case(preset, capacity_scale=capacity_scale, resistance_scale=resistance_scale,
                          start_soc=start_soc, seed=seed, duration_s=duration_s, rest_s=rest_s, dt=dt, c_rate=c_rate,
                          chemistry_curve=chemistry_curve)
    out = []
    for k in range(case.end):
        case.feed(k)
        e = case.estimator.estimate(details=False)
        out.append(((k + 1) * dt, e.soc[0], e.soc_sd[0], case.truth_run.soc[0, k]))
    return PackTrack(case.description.packs[0].name, *(np.array(c, dtype=float) for c in zip(*out)))


@dataclass
class SimulatedCase:
    """``simulated_pack_soc``'s case before the estimator has seen it: the description the
    estimator is told, the truth's pack vector (``variant``) and its run over ``current``
    (states recorded), the first sample past the cut-off (or the length), and the estimator with
    the frames' noise source; ``feed(k)`` gives it sample k."""

    description: object
    truth: np.ndarray
    variant: str
    current: np.ndarray
    dt: float
    truth_run: object
    end: int
    estimator: object
    rng: np.random.Generator

    def feed(self, k: int) -> None:
        spec = self.description.packs[0]
        sd_v = 0.01 + 0.002 * spec.cells_series
        v = float(self.truth_run.voltage[0, k] + self.rng.normal(0.0, sd_v))
        i = float(self.current[k] * (1.0 + self.rng.normal(0.0, 0.01)))
        self.estimator.consume(PackFrame((k + 1) * self.dt, spec.name, v, i, None))


def simulated_case(preset: str, *, capacity_scale: float, resistance_scale: float, start_soc: float, seed: int,
                   duration_s: float = 900.0, rest_s: float = 30.0, dt: float = 1.0,
                   c_rate: tuple[float, float] = (0.5, 2.5), chemistry_curve: bool = False) -> SimulatedCase:
    """The truth and estimator of ``simulated_pack_soc`` (its arguments)."""
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.models import kernel
    from gcs_pdm.models.pack_scaling import scale_pack_vector
    from gcs_pdm.vehicle.model_inputs import model_inputs
    from gcs_pdm.vehicle.presets import PRESETS

    desc = PRESETS[preset]
    spec = desc.packs[0]
    inputs = model_inputs(desc)
    base = inputs.pack_matrix[0]
    truth = scale_pack_vector(base, spec.cells_series, spec.capacity_c, spec.cells_series,
                              spec.capacity_c * capacity_scale, spec.full_cell_v)
    truth = truth * 1.0
    for k in (kernel.I_RS, kernel.I_RCP0, kernel.I_RCP1):
        truth[k] *= resistance_scale
    rng = np.random.default_rng(seed)
    amps = spec.capacity_c / 3600.0
    current = [0.0] * int(rest_s / dt)
    while len(current) * dt < duration_s:
        current += [rng.uniform(*c_rate) * amps] * int(rng.uniform(20, 120) / dt)
    current = np.array(current[: int(duration_s / dt)])
    n = current.size
    if chemistry_curve:
        from gcs_pdm.sim.pack_curves import chemistry_curve_pack

        truth = chemistry_curve_pack(truth, spec.chemistry, spec.cells_series)
        x0 = kernel.initial_extended_state(truth[None], start_soc, 25.0)
        sim = kernel.simulate_packs(truth[None], x0, np.full(n, dt), current[None], np.full(n, 25.0),
                                    variant="extended", record_states=True)
        desc = desc.model_copy(update={"provisional": True})
    else:
        x0 = kernel.initial_pack_state(truth[None], start_soc, 25.0, 0.0)
        sim = kernel.simulate_packs(truth[None], x0, np.full(n, dt), current[None], np.full(n, 25.0),
                                    record_states=True)
    alive = np.flatnonzero(sim.voltage[0] < spec.cutoff_voltage)
    end = int(alive[0]) if alive.size else n
    return SimulatedCase(desc, truth, "extended" if chemistry_curve else "paper", current, dt, sim, end,
                         StateEstimator(vehicle=desc), rng)


#: PyBaMM parameter set -> the chemistry a user would name for such a cell (the prior it starts from):
#: Chen2020 is an LG M50 (NMC811, Li-ion), Marquis2019 a Kokam LCO pouch (a LiPo), Prada2013 an A123
#: ANR26650 (LiFePO4; ``fixtures/pybamm_lfp``)
PYBAMM_CHEMISTRY = {"Chen2020": "liion", "Marquis2019": "lipo", "Prada2013": "lifepo4"}


def pybamm_truth_soc(t: np.ndarray, current: np.ndarray, flight: dict, pack_set: dict) -> np.ndarray:
    """A PyBaMM flight's true SoC at each sample: its initial SoC less the charge drawn over the
    set's true capacity — the charge between its 0 % and 100 % stoichiometries (``set_initial_state``'s
    SoC is a fraction of it), not the nominal capacity: Marquis2019 holds 1.28x its nominal (counted on
    the nominal, its flights went to SoC −0.19 without reaching cut-off), Chen2020 1.03x."""
    true_capacity_c = pack_set.get("cell_window_capacity_ah", pack_set["cell_capacity_ah"]) * pack_set["cells_parallel"] * 3600.0
    drawn = np.concatenate([[0.0], np.cumsum(0.5 * (current[1:] + current[:-1]) * np.diff(t))])
    return flight["initial_soc"] - drawn / true_capacity_c


def pybamm_cell_curve(root: str | Path, set_name: str, base: str) -> "Chemistry":
    """The chemistry ``base`` with a PyBaMM set's own rested curve (``fixtures/pybamm/curves.json``:
    positive − negative electrode potential over the set's stoichiometry window) on its SoC grid:
    what the estimator would know if it had the cell's true curve (to measure what the curve's shape
    costs, ``benchmarks/bench_pybamm_error_sources.py``)."""
    import json
    from dataclasses import replace

    from gcs_pdm.models.chemistry import SOC_GRID, chemistry as chemistry_named

    curves = json.loads((Path(root) / "curves.json").read_text())
    grid, c = np.asarray(curves["stoichiometry"]), curves["sets"][set_name]
    soc = np.asarray(SOC_GRID)
    ocv = (np.interp(c["y_0"] + soc * (c["y_100"] - c["y_0"]), grid, c["positive_v"])
           - np.interp(c["x_0"] + soc * (c["x_100"] - c["x_0"]), grid, c["negative_v"]))
    chem = chemistry_named(base)
    return replace(chem, name=f"{base} ({set_name}'s own curve)", ocv_cell_v=tuple(float(v) for v in ocv),
                   full_cell_v=float(ocv[-1]), max_rest_cell_v=max(chem.max_rest_cell_v, float(ocv[-1]) + 0.05),
                   source=f"PyBaMM {set_name} electrode curves")


def pybamm_flight_soc(root: str | Path, flight: dict, sets: dict, *, chemistry: str | None = None,
                      cells: int = 5, prior=None) -> tuple[PackTrack, dict]:
    """A PyBaMM flight (``fixtures/pybamm``) through a ``PackCalibrator`` started from a chemistry
    prior only: the chemistry's table, the pack's nominal capacity, nothing fitted (``prior``, a
    ``PackPrior``, replaces it: to measure what each part of the prior costs). Truth SoC:
    ``pybamm_truth_soc``.

    Also, on flights that reach cut-off, the time to cut-off the product shows for such a pack
    (``prediction.calibrated_cutoff_quantiles`` at the held current ``CutoffModel.held_current``
    takes, ``TRACE_SAMPLES`` draws: the replay trace's and the service's count-down) against the
    flight's own: at half-way (``predicted_s``, its 5-95 % ``low_s``/``high_s``, ``true_s``) and
    every ``TTC_EVERY_S`` after it while a minute is left (``later``: rows of true, 5 %, 50 %, 95 %;
    ``later_filter_only``: the same with only the filter's covariance drawn, ``without_unmodelled``)."""
    import pyarrow.parquet as pq

    from gcs_pdm.estimation.calibrated_cutoff import CutoffModel
    from gcs_pdm.estimation.calibration import PackCalibrator, PackPrior
    from gcs_pdm.estimation.prediction import calibrated_cutoff_quantiles
    from gcs_pdm.replay.vehicle import TRACE_SAMPLES
    from gcs_pdm.estimation.curve_bank import pack_calibrator

    table = pq.read_table(Path(root) / flight["file"]).to_pydict()
    t = np.asarray(table["time_s"], dtype=float)
    i = np.asarray(table["current_a"], dtype=float)
    v = np.asarray(table["voltage_v"], dtype=float)
    temp = np.asarray(table["temperature_c"], dtype=float)
    s = sets[flight["set"]]
    # the prior: the nominal capacity, what a user reads on the pack (the truth's is not it)
    capacity_c = s["cell_capacity_ah"] * s["cells_parallel"] * 3600.0
    chem = chemistry or PYBAMM_CHEMISTRY[flight["set"]]
    cal = pack_calibrator(prior if prior is not None else PackPrior(chem, cells, capacity_c))
    dt = np.diff(t, prepend=t[0])
    truth = pybamm_truth_soc(t, i, flight, s)
    cutoff_v = cells * flight.get("cell_cutoff_v", math.nan)
    rng, rng_filter_only = np.random.default_rng(0), np.random.default_rng(0)
    out = []
    ttc: dict = {}
    next_ttc_s = t[0] + 0.5 * (t[-1] - t[0])
    for k in range(t.size):
        if not cal.initialised:
            cal.initialise(t[k], v[k], i[k], temp[k])
        else:
            cal.step(t[k], dt[k], i[k], v[k], temp[k])
        out.append((t[k], cal.soc, cal.soc_sd, truth[k]))
        if flight.get("reached_cutoff") and t[k] >= next_ttc_s and t[-1] - t[k] >= (60.0 if ttc else 0.0):
            model = CutoffModel.of(cal)
            held = model.held_current(i[k])
            q = calibrated_cutoff_quantiles(model, held, cutoff_v, rng=rng, n_samples=TRACE_SAMPLES)
            row = (float(t[-1] - t[k]), *(float(x) for x in q))
            if not ttc:
                ttc = {"true_s": row[0], "low_s": row[1], "predicted_s": row[2], "high_s": row[3], "later": [],
                       "later_filter_only": []}
            ttc["later"].append(row)
            q = calibrated_cutoff_quantiles(model.without_unmodelled(), held, cutoff_v, rng=rng_filter_only,
                                            n_samples=TRACE_SAMPLES)
            ttc["later_filter_only"].append((row[0], *(float(x) for x in q)))
            next_ttc_s = t[k] + TTC_EVERY_S
    return PackTrack(flight["flight"], *(np.array(c, dtype=float) for c in zip(*out))), ttc


#: the time to cut-off is asked again this often after half-way (``pybamm_flight_soc``), s
TTC_EVERY_S = 60.0


def simulated_cutoff_case(preset: str, *, capacity_scale: float, resistance_scale: float, start_soc: float,
                          seed: int, c_rate: float = 1.5, spread: float = 0.10, dt: float = 1.0) -> dict:
    """The time to cut-off the service shows for a pack it was never told about, against the truth:
    ``preset``'s first pack on its chemistry's curve, off its label by ``capacity_scale`` and
    ``resistance_scale`` (``sim.pack_curves``), read through the derived prior (the preset marked
    provisional); 30 s of rest at ``start_soc``, then legs of 20-120 s at ``c_rate`` ± ``spread`` of
    the label's capacity until its cut-off; voltage noise 10 mV + 2 mV per cell, current noise 1 %.
    At half-way and every ``TTC_EVERY_S`` after it while a minute is left, the count-down
    (``prediction.calibrated_cutoff_quantiles`` at ``CutoffModel.held_current``, ``TRACE_SAMPLES``
    draws) and the same with only the filter's covariance drawn: ``{"later": rows of (true, 5 %,
    50 %, 95 %), "later_filter_only": ...}`` (empty rows: no cut-off within the flight's hour)."""
    from gcs_pdm.estimation.calibrated_cutoff import CutoffModel
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.estimation.prediction import calibrated_cutoff_quantiles
    from gcs_pdm.models import kernel
    from gcs_pdm.models.pack_scaling import scale_pack_vector
    from gcs_pdm.replay.vehicle import TRACE_SAMPLES
    from gcs_pdm.sim.pack_curves import chemistry_curve_pack
    from gcs_pdm.vehicle.model_inputs import model_inputs
    from gcs_pdm.vehicle.presets import PRESETS

    desc = PRESETS[preset].model_copy(update={"provisional": True})
    spec = desc.packs[0]
    base = model_inputs(desc).pack_matrix[0]
    truth = scale_pack_vector(base, spec.cells_series, spec.capacity_c, spec.cells_series,
                              spec.capacity_c * capacity_scale, spec.full_cell_v)
    for k in (kernel.I_RS, kernel.I_RCP0, kernel.I_RCP1):
        truth[k] *= resistance_scale
    truth = chemistry_curve_pack(truth, spec.chemistry, spec.cells_series)
    rng = np.random.default_rng(seed)
    amps = c_rate * spec.capacity_c / 3600.0
    n_rest, n = int(30.0 / dt), int(3600.0 / dt)
    current = [0.0] * n_rest
    while len(current) < n:
        current += [amps * rng.uniform(1.0 - spread, 1.0 + spread)] * int(rng.uniform(20, 120) / dt)
    current = np.array(current[:n])
    sim = kernel.simulate_packs(truth[None], kernel.initial_extended_state(truth[None], start_soc, 25.0),
                                np.full(n, dt), current[None], np.full(n, 25.0), variant="extended")
    below = np.flatnonzero(sim.voltage[0] < spec.cutoff_voltage)
    out: dict = {"later": [], "later_filter_only": []}
    if not below.size:
        return out
    cut = int(below[0])
    half = n_rest + (cut - n_rest) // 2
    est = StateEstimator(vehicle=desc)
    sd_v = 0.01 + 0.002 * spec.cells_series
    draws, draws_filter_only = np.random.default_rng(0), np.random.default_rng(0)
    next_ask = half
    for k in range(cut - int(60.0 / dt)):
        i_meas = float(current[k] * (1.0 + rng.normal(0.0, 0.01)))
        est.consume(PackFrame((k + 1) * dt, spec.name, float(sim.voltage[0, k] + rng.normal(0.0, sd_v)), i_meas, None))
        if k + 1 < next_ask:
            continue
        model = CutoffModel.of(est.calib[0])
        held = model.held_current(i_meas)
        left = (cut - k - 1) * dt
        for key, m, r in (("later", model, draws), ("later_filter_only", model.without_unmodelled(), draws_filter_only)):
            q = calibrated_cutoff_quantiles(m, held, spec.cutoff_voltage, rng=r, n_samples=TRACE_SAMPLES)
            out[key].append((left, *(float(x) for x in q)))
        next_ask += int(TTC_EVERY_S / dt)
    return out
