"""Speed of the simulated vehicle: ``python benchmarks/bench_sim.py`` prints ONE JSON object on its last line.

Figures: simulated seconds per wall second of a lock-step offline flight (model + kernel + telemetry
encoding at the live default rates and at the recording rates), and the wall time of one physics tick.
"""
from __future__ import annotations

import json
import time

from gcs_pdm.sim.core import warm_up_kernel
from gcs_pdm.sim.model import SimConfig, VehicleModel
from gcs_pdm.sim.record import fly
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.sim.telemetry import RECORDING_RATES, TelemetryConfig


def main() -> None:
    mission = tuple(mission_from_enu([(3000, 0, 150), (3000, 3000, 250), (0, 3000, 120), (-2000, 0, 200)]))
    cfg = SimConfig(mission=mission)
    warm_up_kernel(cfg)
    out: dict = {}
    for label, tel in (("live_rates", TelemetryConfig()), ("recording_rates",
                                                           TelemetryConfig(rates_hz=dict(RECORDING_RATES)))):
        t0 = time.perf_counter()
        rec = fly(cfg, tel)
        wall = time.perf_counter() - t0
        out[f"{label}_sim_s"] = round(rec.final.time_s, 1)
        out[f"{label}_wall_s"] = round(wall, 3)
        out[f"{label}_speedup"] = round(rec.final.time_s / wall, 1)
        out[f"{label}_messages"] = sum(rec.messages.values())
    model = VehicleModel(cfg)
    for _ in range(200):
        model.step()
    n = 2000
    t0 = time.perf_counter()
    for _ in range(n):
        model.step()
    out["model_step_us"] = round(1e6 * (time.perf_counter() - t0) / n, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
