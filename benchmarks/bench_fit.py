"""Benchmark: the paper's full learning procedure for one pack on 8 + 2 + 2 thirty-minute 1 Hz flights.

    python benchmarks/bench_fit.py [--pack LLF20] [--seed 0] [--skip-compare]

Full procedure = cleaning, electrical stage (10 annealing starts, 10 LM runs, selection on
validation), thermal stage (same), test errors of the learned, reference and true parameters.
Also measures why the annealing is batched: cost evaluations per second one vector at a time (as
scipy.optimize.dual_annealing's callback sees them) versus a population of 40 per kernel call, and
the per-evaluation wall time of a short dual_annealing run. Prints ONE JSON object on its last line.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from gcs_pdm.fitting import problem as pb  # noqa: E402
from gcs_pdm.fitting.cleaning import clean_flights  # noqa: E402
from gcs_pdm.fitting.procedure import FitSettings, evaluate_battery, fit_battery  # noqa: E402
from gcs_pdm.fitting.search import SearchSettings  # noqa: E402
from gcs_pdm.fitting.synthetic import generate_flights, synthetic_truth  # noqa: E402
from gcs_pdm.models import kernel  # noqa: E402
from gcs_pdm.models.params import PACK_NAMES, builtin  # noqa: E402


def _compare(train, base) -> dict:
    """Evaluations/s one at a time vs batched; scipy dual_annealing's per-evaluation cost."""
    from scipy.optimize import dual_annealing

    usable, _, _ = clean_flights(train)
    with ThreadPoolExecutor(2) as pool:
        prob = pb.PackProblem(usable, base, pb.BATTERY_ELECTRICAL_BOUNDS, "voltage", mapper=pool.map, workers=2)
        rng = np.random.default_rng(0)
        U = rng.random((200, prob.space.dim))
        prob.mse(U[:2])
        t = time.perf_counter()
        for u in U[:100]:
            prob.mse(u[None], parallel=False)
        single = 100 / (time.perf_counter() - t)
        t = time.perf_counter()
        for k in range(0, 200, 40):
            prob.mse(U[k:k + 40])
        batched = 200 / (time.perf_counter() - t)
        t = time.perf_counter()
        res = dual_annealing(lambda u: float(prob.mse(u[None], parallel=False)[0]), [(0.0, 1.0)] * prob.space.dim,
                             maxfun=300, seed=0, no_local_search=True)
        da_per_eval = (time.perf_counter() - t) / res.nfev
    return {"evals_per_s_single": round(single, 1), "evals_per_s_batched_pop40_2threads": round(batched, 1),
            "batched_speedup": round(batched / single, 2), "dual_annealing_s_per_eval": round(da_per_eval, 5),
            "dual_annealing_nfev": int(res.nfev)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pack", default="LLF20", choices=PACK_NAMES)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-compare", action="store_true")
    args = ap.parse_args()
    truth = synthetic_truth(seed=7)
    t0 = time.perf_counter()
    flights = generate_flights(truth, 12, seed=1, duration_s=1800.0, dt=1.0)
    gen_s = time.perf_counter() - t0
    fl = [f.packs[args.pack] for f in flights]
    settings = FitSettings(search=SearchSettings(starts=10, seed=args.seed))
    kernel.simulate_packs(builtin().pack_matrix()[:1], np.zeros((1, 4)) + [4e5, 0, 0, 20], np.ones(2), np.ones(2), 20.0)
    t0, c0 = time.perf_counter(), time.process_time()
    res = fit_battery(fl[:8], fl[8:10], fl[10:], settings, pack=args.pack)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    i = PACK_NAMES.index(args.pack)
    true_err = evaluate_battery(truth.pack_matrix()[i], fl[10:], settings)["overall"]
    learned = res.errors["learned"]["test"]["overall"]
    ref = res.errors["reference"]["test"]["overall"]

    def figs(o):
        return {"voltage_rmse_v": round(o["voltage"]["rmse"], 4), "voltage_mae_v": round(o["voltage"]["mae"], 4),
                "temperature_rmse_f": round(o["temperature"]["rmse_f"], 3),
                "temperature_mae_f": round(o["temperature"]["mae_f"], 3)}

    true_vec = dict(zip(kernel.PACK_PARAMS, truth.pack_matrix()[i]))
    out = {
        "benchmark": "bench_fit", "pack": args.pack, "flights": "8+2+2 x 1800 s at 1 Hz (synthetic, damaged)",
        "starts": 10, "lm_runs": 10, "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
        # the machine is shared: the load average says how many cores the fit actually had
        "load_average_1min": round(os.getloadavg()[0], 2), "floor_s": 60.0, "under_floor": wall < 60.0,
        "stage_s": {s.name: round(s.seconds, 2) for s in res.stages},
        "evaluations": sum(s.evaluations for s in res.stages),
        "generate_s": round(gen_s, 2), "cpu_count": os.cpu_count(),
        "test_learned": figs(learned), "test_reference_" + res.reference: figs(ref), "test_true_params": figs(true_err),
        "learned_over_true": {k: round(res.parameters[k] / true_vec[k], 3) for k in res.learned},
    }
    if not args.skip_compare:
        out["sa_choice"] = _compare(fl[:8], builtin("previous_si").pack_matrix()[i])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
