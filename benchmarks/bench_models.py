"""Speed of the simulation kernel.

Prints, as one JSON object on its last line: the time of one 30-minute 1 Hz flight for a single
parameter vector, the batched throughput in (parameter vector x step)/s on one thread and on all
cores (``parallel=True``, beside the issue-18 floor of 5e7; also per process CPU-second, the
figure a loaded machine disturbs least), for the paper and the extended variant, the load average while measuring (the machine is shared), the closed-loop
powertrain (4 packs + 2 motors) flight time, and NASA progpy's BatteryCircuit on the same flight
(if progpy is installed: `pip install -e '.[bench]'`).

    python benchmarks/bench_models.py
"""
from __future__ import annotations

import json
import os
import time
import warnings

import numba
import numpy as np

from gcs_pdm.models import kernel as K
from gcs_pdm.models import powertrain as PT
from gcs_pdm.models.params import PACK_CAPACITY_C, default_set, extended_default, perturbed

N_STEPS = 1800  # 30 minutes at 1 Hz


def _best_of(fn, repeat: int) -> float:
    return _best_wall_cpu(fn, repeat)[0]


def _best_wall_cpu(fn, repeat: int) -> tuple[float, float]:
    """Best wall and best process CPU seconds of ``repeat`` calls (CPU counts every thread)."""
    best_wall = best_cpu = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best_wall = min(best_wall, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return best_wall, best_cpu


def flight_profile(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(N_STEPS, dtype=float)
    current = 14 + 6 * np.sin(t / 97.0) + 25 * (((t // 300) % 2 == 0) & (t % 300 < 40)) + rng.normal(0, 1, N_STEPS)
    dt = np.ones(N_STEPS)
    dt[0] = 0.0
    return dt, np.clip(current, 0, None), 20 + 0 * t


def main() -> dict:
    ps = default_set()
    dt, current, ambient = flight_profile()
    p1 = ps.pack_matrix()[:1]
    x1 = K.initial_pack_state(p1, 1.0, 20.0)
    K.simulate_packs(p1, x1, dt, current, ambient)  # compile / load cache
    single = _best_of(lambda: K.simulate_packs(p1, x1, dt, current, ambient), 200)

    n_vec = 2000
    rng = np.random.default_rng(1)
    pb = np.concatenate([perturbed(ps, rng, 0.2).pack_matrix() for _ in range(n_vec // 4)])
    xb = K.initial_pack_state(pb, 1.0, 20.0)
    K.simulate_packs(pb[:2], xb[:2], dt, current, ambient)
    # best of 15: one run is ≈ 50-100 ms, and the second core of a shared host comes and goes
    batched, batched_cpu = _best_wall_cpu(lambda: K.simulate_packs(pb, xb, dt, current, ambient), 15)
    K.simulate_packs(pb[:2], xb[:2], dt, current, ambient, parallel=True)
    batched_par, batched_par_cpu = _best_wall_cpu(
        lambda: K.simulate_packs(pb, xb, dt, current, ambient, parallel=True), 15)

    ext = np.tile(np.array(list(extended_default("lipo").values())), (n_vec, 1))
    ext[:, 0] *= np.exp(rng.uniform(-0.2, 0.2, n_vec))  # vary R_0 so no two vectors are alike
    xe = K.initial_extended_state(ext, 1.0, 20.0)
    K.simulate_packs(ext[:2], xe[:2], dt, current, ambient, variant="extended")
    K.simulate_packs(ext[:2], xe[:2], dt, current, ambient, variant="extended", parallel=True)
    ext_serial = _best_of(lambda: K.simulate_packs(ext, xe, dt, current, ambient, variant="extended"), 3)
    ext_par = _best_of(lambda: K.simulate_packs(ext, xe, dt, current, ambient, variant="extended", parallel=True), 3)

    state = PT.PowertrainState.full(ps, 20.0)
    power = np.full(N_STEPS, float(PT.shaft_power(25.0)))
    PT.fly(ps, state, dt, power, 20.0, record=False)
    powertrain = _best_of(lambda: PT.fly(ps, state, dt, power, 20.0, record=False), 100)

    result = {
        "single_flight_1800_steps_s": single,
        "batched_vectors": n_vec,
        "batched_vector_steps_per_s": n_vec * N_STEPS / batched,
        "batched_vector_steps_per_s_all_cores": n_vec * N_STEPS / batched_par,
        # per CPU-second (what neighbours on a shared machine disturb least); all cores: the CPU
        # time of both threads, so this is per core and the machine's rate is numba_threads × it
        "batched_vector_steps_per_cpu_s": n_vec * N_STEPS / batched_cpu,
        "batched_vector_steps_per_cpu_s_all_cores": n_vec * N_STEPS / batched_par_cpu,
        "extended_batched_vector_steps_per_s": n_vec * N_STEPS / ext_serial,
        "extended_batched_vector_steps_per_s_all_cores": n_vec * N_STEPS / ext_par,
        "floor_vector_steps_per_s_all_cores": 5e7,
        "powertrain_flight_1800_steps_s": powertrain,
        "numba_threads": numba.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    result.update(progpy_reference(dt, current))
    if "progpy_single_flight_s" in result:
        result["speedup_vs_progpy"] = result["progpy_single_flight_s"] / single
    return result


def progpy_reference(dt: np.ndarray, current: np.ndarray) -> dict:
    try:
        from progpy.models import BatteryCircuit
    except Exception as exc:  # optional benchmark dependency
        return {"progpy": f"not installed ({type(exc).__name__})"}
    warnings.filterwarnings("ignore", module="progpy")
    model = BatteryCircuit()
    # progpy's circuit is one 2.2 Ah cell: give it the same C-rate profile as our 7.8 Ah pack
    cell_current = current * model.parameters["CMax"] / PACK_CAPACITY_C

    def load(t, x=None):
        return model.InputContainer({"i": float(cell_current[min(int(t), N_STEPS - 1)])})

    def run():
        model.simulate_to(N_STEPS - 1, load, dt=1.0, save_freq=1.0)

    run()
    return {"progpy_single_flight_s": _best_of(run, 3)}


if __name__ == "__main__":
    print(json.dumps(main()))
