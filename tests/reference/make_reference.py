"""Record today's outputs that the performance work must leave unchanged (issue 18).

    PYTHONPATH=$PWD python tests/reference/make_reference.py

Writes, next to this file:
- ``replay_fixture_flights.json``: per fixture flight (``fixtures/flights/*.tlog``), what
  ``gcs-pdm replay --json`` reports: every fault with its times, the raise/clear events, the
  final estimate (SoC, temperatures, voltages), the pack-health fits and the frame counts;
- ``estimates_synthetic.json``: the estimator's SoC/temperature every 60 s of a synthetic flight;
- ``mc_quantiles.json``: a 100-sample Monte Carlo prediction's quantiles with a fixed seed.

Compared by tests/test_performance_equivalence.py within the tolerances stated there.
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
FLIGHTS = REPO / "fixtures" / "flights"


def replay_outputs(path: Path) -> dict:
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog

    s = replay_tlog(path, mapper=FrameMapper(), frame_consumer=DiagnosisPipeline()).to_dict()
    c = s["consumer"]
    return {"messages": s["messages"], "frames_by_kind": s["frames_by_kind"], "faults": s["faults"],
            "events": c["events"], "estimate": {k: c["estimate"][k] for k in ("time_s", "packs", "motors", "counters")},
            "pack_health": c["pack_health"],
            "prognosis_latest": c["prognosis"]["latest"]}


def synthetic_estimates() -> dict:
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.estimation.synthetic import fly_synthetic
    from gcs_pdm.models.params import default_set
    from gcs_pdm.sim.truth import true_parameters

    flight = fly_synthetic(true_parameters(), np.random.default_rng(7), duration_s=1200.0)
    est = StateEstimator(default_set())
    out, next_t = [], -np.inf
    for fr in flight.frames:
        est.consume(fr)
        if est.time_s >= next_t and est.ready():
            e = est.estimate()
            out.append({"time_s": e.time_s, "soc": e.soc.tolist(), "soc_sd": e.soc_sd.tolist(),
                        "pack_temp_c": e.pack_temp_c.tolist(), "pack_voltage_v": e.pack_voltage_v.tolist(),
                        "motor_temp_c": e.motor_temp_c.tolist()})
            next_t = e.time_s + 60.0
    return {"frames": len(flight.frames), "samples": out, "counters": dict(est.estimate().counters)}


def mc_quantiles() -> dict:
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
    from gcs_pdm.estimation.synthetic import fly_synthetic
    from gcs_pdm.models.params import default_set
    from gcs_pdm.sim.truth import true_parameters

    flight = fly_synthetic(true_parameters(), np.random.default_rng(7), duration_s=600.0)
    est = StateEstimator(default_set())
    for fr in flight.frames:
        est.consume(fr)
    pred = predict_from_estimator(est, FutureLoad.constant(1000.0, 1800.0, 1.0), rng=np.random.default_rng(0),
                                  n_samples=100, trajectories=False)
    return pred.to_dict()


def main() -> int:
    logging.disable(logging.WARNING)
    replay = {p.stem: replay_outputs(p) for p in sorted(FLIGHTS.glob("*.tlog"))}
    (HERE / "replay_fixture_flights.json").write_text(json.dumps(replay, indent=1, sort_keys=True) + "\n")
    (HERE / "estimates_synthetic.json").write_text(json.dumps(synthetic_estimates(), indent=1) + "\n")
    (HERE / "mc_quantiles.json").write_text(json.dumps(mc_quantiles(), indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
