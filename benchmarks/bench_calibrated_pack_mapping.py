"""A self-calibrated pack's learned model flown by the kernel (``estimation.calibrated_pack``) against
the calibrator's own count-down (``CutoffModel``), and what the route risk costs on it (issue 32 item 2).

The case: a quad-4s LiPo the service was never told about (truth 0.8x the label's capacity, 2x its
resistance, on the chemistry's curve) held at 1.5 C from 90 %, the estimator stopped half-way. The mean
state and 64 draws from the filter's covariance are each flown by the kernel's extended step on their
own vector, at the calibrator's temperature (``measured_temperature``) and on the kernel's own thermal
model, to the cut-off, against ``CutoffModel.times`` of the same states. Then ``route_risk`` (100
draws, a 300 s route) with the calibrators and without them (the kernel pack): minimum of 5, ms.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_calibrated_pack_mapping.py`` (one JSON object).
"""
from __future__ import annotations

import copy
import json
import time

import numpy as np

from gcs_pdm.estimation.calibrated_pack import CalibratedCircuit
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.models import kernel
from gcs_pdm.replay.calibration_eval import simulated_case
from gcs_pdm.service.adapters import route_risk


def main() -> None:
    case = simulated_case("quad-4s", capacity_scale=0.8, resistance_scale=2.0, start_soc=0.9, seed=4,
                          duration_s=3000.0, c_rate=(1.5, 1.5), chemistry_curve=True)
    half = 30 + (case.end - 30) // 2
    for k in range(half):
        case.feed(k)
    cal = case.estimator.calib[0]
    circuit = CalibratedCircuit.of(cal, case.estimator.packs.params[0])
    m = circuit.model
    cutoff_v = case.description.packs[0].cutoff_voltage
    held_a = m.held_current(1.5 * cal.q0 / 3600.0)
    out = {}
    for name, at_reading in (("measured_temperature", True), ("own_thermal_model", False)):
        states = np.vstack([m.x[None], m.draw_states(np.random.default_rng(3), 64)])
        x0 = circuit.pack_states(states, cal.temp_c)
        kw = dict(measured_temperature=np.full(2000, cal.temp_c)) if at_reading else {}
        run = kernel.simulate_packs(circuit.vectors(states), x0, np.ones(2000), np.full((len(states), 2000), held_a),
                                    np.full(2000, 25.0), variant="extended", **kw)
        below = run.voltage < cutoff_v
        flown = np.where(below.any(axis=1), below.argmax(axis=1) + 1.0, np.inf)
        own = m.times(states, held_a, cutoff_v)
        rel = flown / own - 1
        out[name] = dict(mean_state_kernel_s=float(flown[0]), mean_state_cutoffmodel_s=round(float(own[0]), 1),
                         draws_rel_diff_median=round(float(np.median(np.abs(rel[1:]))), 4),
                         draws_rel_diff_p95=round(float(np.quantile(np.abs(rel[1:]), 0.95)), 4),
                         corr=round(float(np.corrcoef(flown[1:], own[1:])[0, 1]), 4),
                         kernel_q=[float(q) for q in np.quantile(flown[1:], [0.05, 0.5, 0.95])],
                         own_q=[round(float(q), 1) for q in np.quantile(own[1:], [0.05, 0.5, 0.95])])
    out["truth_left_s"] = case.end - half
    load = FutureLoad.constant(120.0, 300.0, 5.0, 25.0)
    kernel_only = copy.deepcopy(case.estimator)
    kernel_only.calib = [None]
    for name, est in (("calibrated", case.estimator), ("kernel_path", kernel_only)):
        route_risk(est, load, [])
        times_s = []
        for _ in range(5):
            t0 = time.perf_counter()
            route_risk(est, load, [])
            times_s.append(time.perf_counter() - t0)
        out[f"route_risk_100_ms_{name}"] = round(1000 * min(times_s), 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
