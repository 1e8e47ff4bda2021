"""Speed of the state estimator and the Monte Carlo prediction (issue 6 floors), vs progpy.

Prints its figures as ONE JSON object on the last line:

- ``update_4packs_2motors_us``: one estimator update of all four packs and both motors (the two
  batched filter steps: 32 pack sigma points in one kernel call, 4 motor sigma points in another)
  — floor 1000 µs;
- ``consume_per_frame_us``: ``StateEstimator.consume`` per telemetry frame on a synthetic flight;
- ``pipeline_per_frame_us``: the whole ``DiagnosisPipeline`` per frame (estimator, detectors,
  and the prognosis' Monte Carlo every 30 s of message time, amortised);
- ``mc_100_30min_s``: a 100-sample Monte Carlo prediction of time to cut-off 30 minutes ahead
  (1 s steps, one ``simulate_powertrain`` call with ``stop_on_failure``) — floor 0.1 s; with the
  median trajectories as well: ``mc_100_30min_with_trajectories_s``;
- progpy (if installed): ``progpy_pf_update_100_us`` — ParticleFilter over BatteryCircuit (one
  cell, 100 particles), one update; ``progpy_mc_100_30min_s_est`` — its MonteCarlo predictor,
  measured on 10 samples and scaled ×10 (the full run takes tens of seconds).

Run: ``python benchmarks/bench_estimate.py``
"""
from __future__ import annotations

import json
import time
import warnings

import numpy as np

from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
from gcs_pdm.estimation.synthetic import fly_synthetic
from gcs_pdm.models.params import default_set
from gcs_pdm.sim.truth import true_parameters


def best_of(fn, repeat: int, number: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def main() -> dict:
    ps = default_set()
    flight = fly_synthetic(true_parameters(), np.random.default_rng(7), duration_s=1200.0)
    est = StateEstimator(ps)
    for fr in flight.frames:
        est.consume(fr)
    # warm-up done by the flight; now the batched update of everything
    idx4, idx2 = np.arange(4), np.arange(2)
    v, _ = est.packs.voltage()
    tp, _ = est.packs.temperature()
    tm, _ = est.motors.temperature()

    def update():
        est.packs.step(idx4, np.full(4, 0.5), np.full(4, 12.0), 20.0, v, tp)
        est.motors.step(idx2, np.full(2, 0.5), np.full(2, 12.0), 20.0, tm)

    result = {"update_4packs_2motors_us": round(best_of(update, 5, 200) * 1e6, 1)}

    def consume_all():
        e = StateEstimator(ps)
        for fr in flight.frames:
            e.consume(fr)

    per_flight = best_of(consume_all, 3, 1)
    result["consume_per_frame_us"] = round(per_flight / len(flight.frames) * 1e6, 1)
    result["frames_per_flight"] = len(flight.frames)

    def pipeline_all():
        p = DiagnosisPipeline(ps)
        p.set_mission(FutureLoad(np.diff(flight.time_s, prepend=flight.time_s[0]), flight.shaft_power_w, 20.0),
                      flight.time_s[0])
        for fr in flight.frames:
            p.consume(fr)

    t_pipe = best_of(pipeline_all, 2, 1)
    result["pipeline_per_frame_us"] = round(t_pipe / len(flight.frames) * 1e6, 1)
    result["pipeline_flight_s"] = round(t_pipe, 3)
    result["flight_duration_s"] = round(flight.duration_s, 1)

    load = FutureLoad.constant(1000.0, 1800.0, 1.0)
    rng = np.random.default_rng(0)
    result["mc_100_30min_s"] = round(best_of(lambda: predict_from_estimator(
        est, load, rng=rng, n_samples=100, trajectories=False), 5, 3), 4)
    result["mc_100_30min_with_trajectories_s"] = round(best_of(lambda: predict_from_estimator(
        est, load, rng=rng, n_samples=100, trajectories=True), 3, 2), 4)
    result["floors"] = {"update_us": 1000, "mc_100_30min_s": 0.1}
    result.update(progpy_reference())
    return result


def progpy_reference() -> dict:
    try:
        from progpy.models import BatteryCircuit
        from progpy.predictors import MonteCarlo
        from progpy.state_estimators import ParticleFilter
        from progpy.uncertain_data import MultivariateNormalDist
    except ImportError:
        return {"progpy": "not installed"}
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = BatteryCircuit()
        x0 = m.initialize()
        pf = ParticleFilter(m, x0, num_particles=100)
        u = m.InputContainer({"i": 2.0})
        x = x0
        t = 0.0
        zs = []
        for _ in range(30):
            t += 1.0
            x = m.next_state(x, u, 1.0)
            zs.append((t, m.output(x)))
        k = [0]

        def pf_step():
            tt, z = zs[k[0] % len(zs)]
            pf.estimate(tt + 30.0 * (k[0] // len(zs)), u, z)
            k[0] += 1

        out["progpy_pf_update_100_us"] = round(best_of(pf_step, 3, 20) * 1e6, 1)
        mc = MonteCarlo(m)
        x_dist = MultivariateNormalDist(list(x.keys()), list(x.values()), np.diag([1e-6] * len(x)))

        def future_load(t, x=None):
            return u

        t0 = time.perf_counter()
        mc.predict(x_dist, future_load, n_samples=10, dt=1.0, horizon=1800, save_freq=60)
        out["progpy_mc_10_30min_s"] = round(time.perf_counter() - t0, 3)
        out["progpy_mc_100_30min_s_est"] = round(10 * out["progpy_mc_10_30min_s"], 2)
    return out


if __name__ == "__main__":
    print(json.dumps(main()))
