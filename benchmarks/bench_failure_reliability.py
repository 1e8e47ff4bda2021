"""Is the P(failure) a proposal and ``/status.outlook`` show a true probability? (a reliability curve)

Per preset: ``bench_risk_presets.py``'s field (ten goals within two minutes' flight, the second motor
at ``--fault`` power loss), flown from a range of starting SoCs (``--socs``). Two kinds of route:

* **assessed** (what ``/status.outlook`` shows for the current mission): the survey — every goal in
  nearest-neighbour order — and its shorter prefixes (``--legs``), each judged as the service
  judges a route (``RiskSimulator.risk_of`` on ``--samples`` draws: the prior parameter spread of a
  pack nothing has narrowed, ``Uncertainty(wind_sd_mps=1.5)`` as with a wind estimate);
* **planned** (what a proposal shows): the risk-bounded planner's choice (``run_risk_bounded("pf")``
  at ε = ``--epsilon``) from each start, and its P(failure) verdict.

Each route is then flown by ``--truths`` hidden truths (a fresh seed per route: not the draws):
every parameter spread by 8.7 % (the simulated vehicle's hidden truth, ``sim.truth``: ±15 %
log-uniform), the start SoC 2 %, a fault 0.08 and the wind 1.5 m/s about the stated ones. A truth
fails when it does not land (a pack cut-off or a motor limit in the air).

Reported: a reliability table over bins of predicted P (routes x truths; count, mean predicted,
observed failure rate with a Clopper-Pearson 90 % interval), the Brier score (and the Brier score of
always predicting the overall rate, for scale), and the observed failure rate among routes given
P <= ε (the planner's default ``max_failure_probability``: what an operator relies on), and among
those the draws did not call certain (0 < P <= ε). ``--truth-param-sd 0.08``: truths spread as the
draws' own prior (an in-model check: what is left is the Monte Carlo's own error).

    python benchmarks/bench_failure_reliability.py [--presets NAME ...] [--truths 100] [--samples 200]
        [--socs 0.25 0.3 ...] [--legs 1 2 ...] [--truth-param-sd 0.0866] [--no-planned]

Prints one line per preset and start (each route: P said / share of truths failed), the tables, then the figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import beta

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_risk_presets import PRESET_NAMES, TRUTH_PARAM_SD, field, fly_truths  # noqa: E402
from gcs_pdm.planning.planners import run_risk_bounded  # noqa: E402
from gcs_pdm.planning.risk import RiskSimulator, Uncertainty, draw, prior_spread  # noqa: E402
from gcs_pdm.planning.simulator import VehicleSimulator  # noqa: E402
from gcs_pdm.vehicle.presets import PRESETS  # noqa: E402

#: the planner's default ``max_failure_probability`` (service config)
DEFAULT_EPSILON = 0.02
#: the bins' upper edges of predicted P (the first bin is P <= 0.02: the planner's default bound)
BIN_EDGES = (0.0, 0.02, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0)


def make_sim(desc, start_soc: float, fault: float) -> VehicleSimulator:
    """The field of ``bench_risk_presets`` with the packs at ``start_soc`` and the second motor (or
    the only one) at ``fault`` power loss."""
    from gcs_pdm.models import kernel
    from gcs_pdm.models.powertrain import PowertrainState
    from gcs_pdm.vehicle.model_inputs import model_inputs

    inputs = model_inputs(desc)
    state = PowertrainState(kernel.initial_pack_state(inputs.pack_matrix, start_soc, 20.0),
                            np.full(inputs.n_motors, 20.0))
    motor = desc.motor_names[min(1, len(desc.motor_names) - 1)]
    return VehicleSimulator(field(desc), vehicle=desc, state=state, motor_faults={motor: fault} if fault else {})


def survey_order(sim: VehicleSimulator) -> list[int]:
    """Every goal (scenario index) in nearest-neighbour order from the start."""
    pts = np.array([(w.east_m, w.north_m) for w in sim.scenario.waypoints])
    here, left, order = np.array([sim.scenario.start.east_m, sim.scenario.start.north_m]), list(range(len(pts))), []
    while left:
        k = min(left, key=lambda i: float(np.hypot(*(pts[i] - here))))
        order.append(k)
        left.remove(k)
        here = pts[k]
    return order


def judge(sim: VehicleSimulator, samples: int, seed: int, epsilon: float) -> RiskSimulator:
    """The service's risk judge of a route with no estimator: the prior spread, wind known."""
    return RiskSimulator(sim, draw(sim, samples, uncertainty=Uncertainty(wind_sd_mps=1.5), seed=seed,
                                   spread=prior_spread(len(sim.pack_names))),
                         max_failure_probability=epsilon)


def truths_fail(sim: VehicleSimulator, route, truths: int, seed: int, param_sd: float = TRUTH_PARAM_SD) -> np.ndarray:
    """(truths,) bool: which hidden truths (every parameter log-spread by ``param_sd``) fail to land
    flying ``route``."""
    drawn = draw(sim, truths, uncertainty=Uncertainty(param_rel_sigma=param_sd), seed=seed)
    return ~fly_truths(sim, drawn, route)[1]


def clopper_pearson(k: int, n: int, level: float = 0.90) -> tuple[float, float]:
    """The exact binomial ``level`` interval of a rate with ``k`` successes in ``n`` trials."""
    if n <= 0:
        raise ValueError("an interval of no trials")
    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def reliability(predicted: np.ndarray, failed: np.ndarray, edges=BIN_EDGES) -> list[dict]:
    """Per bin of predicted P (the first holds P <= edges[1]; then (edges[i], edges[i+1]]): its
    count, mean predicted, observed failure rate and its 90 % interval. Empty bins are left out."""
    predicted, failed = np.asarray(predicted, dtype=float), np.asarray(failed, dtype=bool)
    if predicted.shape != failed.shape:
        raise ValueError(f"{predicted.shape} predictions, {failed.shape} outcomes")
    if np.any((predicted < 0) | (predicted > 1)):
        raise ValueError("a predicted probability outside [0, 1]")
    which = np.clip(np.searchsorted(np.asarray(edges), predicted, side="left") - 1, 0, len(edges) - 2)
    rows = []
    for b in range(len(edges) - 1):
        sel = which == b
        n = int(sel.sum())
        if not n:
            continue
        k = int(failed[sel].sum())
        rows.append({"bin": [edges[b], edges[b + 1]], "count": n, "mean_predicted": round(float(predicted[sel].mean()), 4),
                     "observed": round(k / n, 4), "observed_90": [round(v, 4) for v in clopper_pearson(k, n)]})
    return rows


def brier(predicted: np.ndarray, failed: np.ndarray) -> dict:
    """The Brier score, and the score of always predicting the observed overall rate (for scale)."""
    p, y = np.asarray(predicted, dtype=float), np.asarray(failed, dtype=float)
    return {"brier": round(float(np.mean((p - y) ** 2)), 4),
            "brier_climatology": round(float(np.mean((y.mean() - y) ** 2)), 4)}


def summary(predicted, failed, epsilon: float) -> dict:
    predicted, failed = np.asarray(predicted, dtype=float), np.asarray(failed, dtype=bool)
    out = {"pairs": int(predicted.size), "table": reliability(predicted, failed), **brier(predicted, failed)}
    # all routes allowed at the bound, and those the draws did not call certain (0 < P <= ε): the
    # first is dominated by routes far from any limit, the second is the bound's own claim
    for key, sel in (("given_p_le_epsilon", predicted <= epsilon),
                     ("given_0_lt_p_le_epsilon", (predicted > 0) & (predicted <= epsilon))):
        if sel.any():
            k, n = int(failed[sel].sum()), int(sel.sum())
            out[key] = {"epsilon": epsilon, "pairs": n, "mean_predicted": round(float(predicted[sel].mean()), 4),
                        "observed": round(k / n, 4), "observed_90": [round(v, 4) for v in clopper_pearson(k, n)]}
        else:
            out[key] = {"epsilon": epsilon, "pairs": 0, "observed": None, "why": "no route was given such a P"}
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--presets", nargs="*", default=list(PRESET_NAMES))
    ap.add_argument("--socs", nargs="*", type=float, default=[0.25, 0.35, 0.45, 0.55, 0.7])
    ap.add_argument("--legs", nargs="*", type=int, default=list(range(1, 11)), help="survey prefixes assessed")
    ap.add_argument("--fault", type=float, default=0.6)
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--truths", type=int, default=100)
    ap.add_argument("--epsilon", type=float, default=DEFAULT_EPSILON)
    ap.add_argument("--truth-param-sd", type=float, default=TRUTH_PARAM_SD,
                    help="the truths' parameter log-spread (0.08: the draws' own prior, an in-model check)")
    ap.add_argument("--no-planned", action="store_true", help="assessed routes only")
    args = ap.parse_args()
    t0, c0 = time.perf_counter(), time.process_time()
    pred = {"assessed": [], "planned": []}
    fail = {"assessed": [], "planned": []}
    routes = []
    seed = 0
    for name in args.presets:
        desc = PRESETS[name]
        for soc in args.socs:
            sim = make_sim(desc, soc, args.fault)
            order = survey_order(sim)
            rs = judge(sim, args.samples, seed, args.epsilon)
            cands = [("assessed", tuple(order[:k])) for k in args.legs if k <= len(order)]
            if not args.no_planned:
                plan = run_risk_bounded("pf", rs, seed=seed)
                cands.append(("planned", tuple(plan.route)))
            for kind, route in cands:
                seed += 1
                p = rs.risk_of(route)["p_failure"]
                failed = truths_fail(sim, route, args.truths, seed=100_000 + seed, param_sd=args.truth_param_sd)
                pred[kind].append(np.full(failed.size, p))
                fail[kind].append(failed)
                routes.append({"preset": name, "start_soc": soc, "kind": kind, "legs": len(route),
                               "p_failure": round(p, 4), "truth_failure_rate": round(float(failed.mean()), 4)})
            rows = [r for r in routes if r["preset"] == name and r["start_soc"] == soc]
            print(f"{name:9s} SoC {soc:.2f}: " + ", ".join(f"{r['kind'][0]}{r['legs']} P {r['p_failure']:.3f}/"
                                                           f"{r['truth_failure_rate']:.3f}" for r in rows),
                  f"(load {os.getloadavg()[0]:.1f})", flush=True)
    out = {"presets": args.presets, "socs": args.socs, "legs": args.legs, "fault": args.fault, "samples": args.samples,
           "truths_per_route": args.truths, "truth_param_sd": args.truth_param_sd}
    kinds = [k for k in ("assessed", "planned") if pred[k]]
    for kind in kinds + ["all"]:
        ks = kinds if kind == "all" else [kind]
        out[kind] = summary(np.concatenate([a for k in ks for a in pred[k]]),
                            np.concatenate([a for k in ks for a in fail[k]]), args.epsilon)
    out["routes"] = routes
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    out["cpu_s"] = round(time.process_time() - c0, 1)
    out["load_average_1min"] = os.getloadavg()[0]
    for kind in kinds + ["all"]:
        s = out[kind]
        print(f"{kind}: {s['pairs']} route x truth pairs, Brier {s['brier']} (always the overall rate: "
              f"{s['brier_climatology']}); given P <= {args.epsilon}: {s['given_p_le_epsilon']}; "
              f"given 0 < P <= {args.epsilon}: {s['given_0_lt_p_le_epsilon']}")
        for r in s["table"]:
            print(f"  P in {r['bin']}: n {r['count']:5d} mean P {r['mean_predicted']:.3f} observed "
                  f"{r['observed']:.3f} {r['observed_90']}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
