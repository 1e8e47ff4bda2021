"""How far a route's predicted landing SoC moves towards the truth when a self-calibrated pack flies
its filter's learned model (``estimation.calibrated_pack``) instead of the description's kernel pack
with only the calibrated SoC (issue 32 item 2).

The cases: issue 29's simulated chemistry-curve packs (``calibration_eval.simulated_case``,
``bench_soc_calibration.SIM_CASES``: capacity 0.7-1.3x, resistance 0.5-3x, starts 50-100 %) on the
single-pack presets, each flown ``STOP_S`` of its 0.5-2.5 C legs (or to 60 s before its cut-off),
the estimator stopped there. The route: a constant shaft power drawing about 1.5 C on the truth, long
enough for the truth to use half its charge above 10 %. The truth flies the same load
(``topology.simulate_vehicle_extended`` from its state at the stop, the estimator's motors); the
prediction is ``service.adapters.route_risk`` (100 draws), once as the product has it and once with
the calibrators hidden (the kernel path). The figure: the median landing SoC's error.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_calibrated_pack_route.py`` (prints one line per
case, then ONE JSON object).
"""
from __future__ import annotations

import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_soc_calibration import SIM_CASES  # noqa: E402

from gcs_pdm.estimation.prediction import FutureLoad  # noqa: E402
from gcs_pdm.models import kernel, topology  # noqa: E402
from gcs_pdm.replay.calibration_eval import simulated_case  # noqa: E402
from gcs_pdm.service.adapters import route_risk  # noqa: E402
from gcs_pdm.vehicle.model_inputs import model_inputs  # noqa: E402

PRESETS = ("plane-3s", "quad-4s", "quad-6s")  # one pack each: the pack flown is the vehicle's
STOP_S = 450


def truth_landing(case, inputs, motors, k_stop: int, load: FutureLoad) -> tuple[float, bool]:
    """The truth's SoC at the end of ``load`` from its state after sample ``k_stop``, and whether it
    reached its cut-off on the way."""
    x0 = case.truth_run.states[0, k_stop][None, None]
    run = topology.simulate_vehicle_extended(inputs.topology, inputs.pack_matrix[None], case.truth[None, None],
                                             np.ones(1, dtype=bool), motors[None], x0, np.full((1, motors.shape[0]), 25.0),
                                             load.dt, load.shaft_power_w, load.ambient_c, record=True)
    return float(run.pack_soc[0, -1, 0]), bool(run.pack_end_step[0, 0] >= 0)


def shaft_power_for(case, inputs, motors, k_stop: int, amps: float) -> float:
    """The shaft power at which the truth draws about ``amps`` now (two secant steps)."""
    def drawn(p):
        load = FutureLoad.constant(p, 5.0, 1.0, 25.0)
        x0 = case.truth_run.states[0, k_stop][None, None]
        run = topology.simulate_vehicle_extended(inputs.topology, inputs.pack_matrix[None], case.truth[None, None],
                                                 np.ones(1, dtype=bool), motors[None], x0,
                                                 np.full((1, motors.shape[0]), 25.0), load.dt, load.shaft_power_w,
                                                 load.ambient_c, record=True)
        return float(run.pack_current[0, -1, 0])

    p = amps * case.truth_run.voltage[0, k_stop] * 0.8
    for _ in range(3):
        p *= amps / max(drawn(p), 1e-6)
    return p


def main() -> None:
    t0 = time.process_time()
    rows = []
    for preset in PRESETS:
        for cap, res, start, seed in SIM_CASES:
            case = simulated_case(preset, capacity_scale=cap, resistance_scale=res, start_soc=start, seed=seed,
                                  chemistry_curve=True)
            k_stop = min(STOP_S, case.end - 60) - 1
            for k in range(k_stop + 1):
                case.feed(k)
            est = case.estimator
            inputs = model_inputs(case.description)
            motors = np.asarray(est.motors.params, dtype=np.float64)
            spec = case.description.packs[0]
            amps = 1.5 * spec.capacity_c / 3600.0
            power = shaft_power_for(case, inputs, motors, k_stop, amps)
            soc_now = float(case.truth_run.soc[0, k_stop])
            q_true = float(case.truth[kernel.E_CMAX])
            duration = max(60.0, 0.5 * (soc_now - 0.1) * q_true / amps)
            load = FutureLoad.constant(power, duration, 5.0, 25.0)
            truth, truth_cut = truth_landing(case, inputs, motors, k_stop, load)
            product = route_risk(est, load, [])
            kernel_only = copy.deepcopy(est)
            kernel_only.calib = [None] * len(kernel_only.calib)
            before = route_risk(kernel_only, load, [])

            def med(r):
                v = r["landing_soc"]["p50"]
                return float("nan") if v is None else v

            row = dict(preset=preset, capacity=cap, resistance=res, start=start, stop_s=k_stop + 1,
                       route_s=round(duration), truth=round(truth, 4), truth_cut_off=truth_cut,
                       kernel_path=round(med(before), 4), calibrated=round(med(product), 4),
                       p_failure_kernel=before["failure_probability"], p_failure_calibrated=product["failure_probability"],
                       calibrated_p05_p95=[product["landing_soc"]["p05"], product["landing_soc"]["p95"]])
            rows.append(row)
            print(json.dumps(row), flush=True)
    err_k = np.array([abs(r["kernel_path"] - r["truth"]) for r in rows])
    err_c = np.array([abs(r["calibrated"] - r["truth"]) for r in rows])
    holds = [r["calibrated_p05_p95"][0] is not None and r["calibrated_p05_p95"][0] <= r["truth"] <= r["calibrated_p05_p95"][1]
             for r in rows]
    print(json.dumps({
        "cases": len(rows),
        "landing_soc_abs_error_kernel_path": {"median": round(float(np.nanmedian(err_k)), 4), "max": round(float(np.nanmax(err_k)), 4)},
        "landing_soc_abs_error_calibrated": {"median": round(float(np.nanmedian(err_c)), 4), "max": round(float(np.nanmax(err_c)), 4)},
        "within_0.05_kernel_path": int(np.sum(err_k <= 0.05)), "within_0.05_calibrated": int(np.sum(err_c <= 0.05)),
        "closer_with_calibrated": int(np.sum(err_c < err_k)),
        "calibrated_5_95_holds_truth": int(sum(holds)),
        "cpu_s": round(time.process_time() - t0, 1),
    }))


if __name__ == "__main__":
    main()
