"""Planner benchmark: exact optimum and solve time; PF and PF+local search over seeded trials.

Scenarios: table3_{7,8,9,10} (fixtures/scenarios: the fault half way from waypoint 2 to 3, planning
over the 5..8 waypoints not yet visited) and preflight_10 (all ten waypoints free, the fault known
before take-off) and random12_101 (twelve seeded random waypoints, all free: the exact search's
scaling). Planning model: the scenario's own parameter set (paper_si). Reward = the
planner's reward on that model (the same model the exact optimum is computed on).

    python benchmarks/bench_planner.py [--trials 30] [--particles 30]

Prints one line per scenario, then the figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs_pdm.planning.exact import exact_search  # noqa: E402
from gcs_pdm.planning.local_search import pf_local_search  # noqa: E402
from gcs_pdm.planning.particle_filter import particle_filter  # noqa: E402
from gcs_pdm.planning.scenario import Scenario  # noqa: E402
from gcs_pdm.planning.simulator import VehicleSimulator  # noqa: E402
from gcs_pdm.planning.table3_scenario import preflight_scenario, random_field_scenario  # noqa: E402


def timed(fn, *a, **kw):
    t = time.perf_counter()
    out = fn(*a, **kw)
    return out, time.perf_counter() - t


def trials(fn, sim, n, particles):
    rewards, times = [], []
    for seed in range(n):
        p, t = timed(fn, sim, particles=particles, seed=seed)
        assert p.feasible or not p.route
        rewards.append(p.reward)
        times.append(t)
    r = np.array(rewards)
    return {"mean": float(r.mean()), "std": float(r.std()), "min": float(r.min()),
            "median_time_s": float(np.median(times)), "max_time_s": float(np.max(times))}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--particles", type=int, default=30)
    args = ap.parse_args()
    scenarios = [Scenario.from_json((ROOT / "fixtures" / "scenarios" / f"table3_{n}.json").read_text())
                 for n in (7, 8, 9, 10)]
    scenarios.append(preflight_scenario(10))
    scenarios.append(random_field_scenario(12, seed=101))
    # compile/load the kernel outside the timings
    warm = VehicleSimulator.for_scenario(scenarios[0])
    particle_filter(warm, particles=2, seed=0)
    exact_search(warm)
    out: dict = {"trials": args.trials, "particles": args.particles, "scenarios": {}}
    floors_ok = True
    for sc in scenarios:
        sim = VehicleSimulator.for_scenario(sc)
        ex, t_ex = timed(exact_search, sim)
        pf = trials(particle_filter, sim, args.trials, args.particles)
        ls = trials(pf_local_search, sim, args.trials, args.particles)
        if len(sc.waypoints) <= 10:
            ex_as, t_as = timed(exact_search, VehicleSimulator.for_scenario(sc, optimise_airspeed=True))
            airspeed = {"reward": ex_as.reward, "route": list(ex_as.numbers), "time_s": t_as}
        else:  # slower legs keep many more routes feasible: not part of this figure
            airspeed = None
        row = {
            "free_waypoints": len(sc.waypoints),
            "exact": {"reward": ex.reward, "route": list(ex.numbers), "time_s": t_ex, "nodes": ex.stats["nodes"]},
            "pf": {**pf, "pct_of_exact": 100.0 * pf["mean"] / ex.reward},
            "pfls": {**ls, "pct_of_exact": 100.0 * ls["mean"] / ex.reward},
            "exact_airspeed_optimised": airspeed,
        }
        # floors: PF+LS within 0.5 % of the optimum everywhere; at 10 waypoints (table3_10 is the
        # paper's 10-waypoint scenario, preflight_10 has ten free) PF+LS median < 1 s, exact < 10 s
        # (random12 has no floor: it shows how the search scales past the issue's range)
        if sc.name.startswith(("table3_", "preflight_")):
            ok = row["pfls"]["pct_of_exact"] >= 99.5
            if sc.name in ("table3_10", "preflight_10"):
                ok = ok and ls["median_time_s"] < 1.0 and t_ex < 10.0
            row["floors_ok"] = ok
            floors_ok &= ok
        out["scenarios"][sc.name] = row
        print(f"{sc.name:<13} free {len(sc.waypoints):>2}  exact {ex.reward:6.1f} in {t_ex:6.3f} s | "
              f"PF {pf['mean']:6.1f}({pf['std']:4.1f}) {row['pf']['pct_of_exact']:5.1f}% med {pf['median_time_s']*1e3:6.1f} ms | "
              f"PF+LS {ls['mean']:6.1f}({ls['std']:4.1f}) {row['pfls']['pct_of_exact']:5.1f}% med {ls['median_time_s']*1e3:6.1f} ms | "
              f"exact w/ airspeed opt {airspeed['reward'] if airspeed else float('nan'):6.1f}", flush=True)
    out["floors_ok"] = floors_ok
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
