"""Route risk benchmark: ``adapters.route_risk`` (a proposal's probability of failure, 100 Monte
Carlo samples in one batched ``predict_from_estimator`` call) on the paper's aircraft (the Table III
preflight route, ~2000 s) and on ``quad-4s`` (a five-goal tour of 1.8 km radius, ~1500 s).

    python benchmarks/bench_route_risk.py

The per-sample loop it replaced (100 one-sample calls) took ``cpu_s_per_call`` in
tests/reference/route_risk_per_sample_loop.json on the paper aircraft. Prints the figures as ONE
JSON object on the last line (CPU and wall per call, best of 5).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from measure import timed  # noqa: E402

from gcs_pdm.estimation.estimator import StateEstimator  # noqa: E402
from gcs_pdm.estimation.synthetic import fly_synthetic  # noqa: E402
from gcs_pdm.frames import MotorFrame, PackFrame  # noqa: E402
from gcs_pdm.models.powertrain import DescribedMotorFault, MotorFault  # noqa: E402
from gcs_pdm.planning.simulator import VehicleSimulator, original_order  # noqa: E402
from gcs_pdm.planning.table3_scenario import preflight_scenario  # noqa: E402
from gcs_pdm.service import adapters  # noqa: E402
from gcs_pdm.sim.truth import true_parameters  # noqa: E402
from gcs_pdm.vehicle.presets import PRESETS  # noqa: E402
from test_planning_vehicle import _scenario  # noqa: E402


def paper_case():
    est = StateEstimator(true_parameters())
    for fr in fly_synthetic(true_parameters(), np.random.default_rng(2), duration_s=150.0, initial_soc=1.0).frames:
        est.consume(fr)
    sim = VehicleSimulator.for_scenario(preflight_scenario(10), true_parameters())
    return est, adapters.route_load(sim, original_order(sim.scenario)), (MotorFault("aft", 0.7),)


def quad_case():
    desc = PRESETS["quad-4s"]
    est = adapters.make_estimator(desc)
    for t in range(3):
        est.consume(PackFrame(float(t), "battery", 16.0, 11.0, 25.0))
        for m in desc.motor_names:
            est.consume(MotorFrame(float(t), m, 2.75, 5000.0, 30.0))
    sim = VehicleSimulator(_scenario(1800.0, 8.0), vehicle=desc, state=est.powertrain_state())
    return est, adapters.route_load(sim, original_order(sim.scenario)), (DescribedMotorFault("m4", 0.6),)


def main() -> int:
    ref = json.loads((ROOT / "tests" / "reference" / "route_risk_per_sample_loop.json").read_text())
    out: dict = {"n_samples": adapters.ROUTE_RISK_SAMPLES,
                 "paper_per_sample_loop_cpu_s_recorded": ref["cpu_s_per_call"]}
    for name, case in (("paper", paper_case), ("quad_4s", quad_case)):
        est, load, faults = case()
        adapters.route_risk(est, load, faults, seed=0)  # compile/load the kernel outside the timing
        r = timed(lambda: adapters.route_risk(est, load, faults, seed=0), repeat=5)
        p = adapters.route_risk(est, load, faults, seed=0)["failure_probability"]
        out[name] = {**r, "load_steps": int(np.size(load.dt)), "load_s": round(load.duration_s, 1),
                     "failure_probability": p}
        print(f"{name:<8} {r['cpu_s'] * 1e3:7.1f} ms CPU ({r['wall_s'] * 1e3:7.1f} wall) per route, "
              f"{np.size(load.dt)} steps, p_fail {p}", flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
