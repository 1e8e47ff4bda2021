"""Table III rebuilt: the planners with prior and learned parameters, scored on the true vehicle.

For each sub-scenario (waypoints 1..n, the fault half way from 2 to 3, planning over 3..n):

* ℛ — the exact optimum on the true vehicle model (the best any planner could score);
* the particle filter (K particles) over ``trials`` seeded trials planning with the prior
  ("previous") parameters, and the same trials planning with the learned parameters;
* the stronger planner (PF + local search) with the learned parameters.

Scoring ("rewards scored by the true vehicle model"): the chosen route is flown on the truth from
the same start, and judged by the rules the planners were given: it scores the rewards of its
waypoints if the true vehicle gets home inside every limit with the landing reserve kept, and 0
otherwise. A vehicle lost before landing (pack cut-off or depletion, a temperature limit) is
counted as "lost"; one that lands inside the reserve — the operator's safety margin, which the
plan promised to keep — is counted as "reserve missed". A model that is optimistic about energy
thus pays for the plans it could not keep. Two references: ℛ is the exact optimum on the truth
under those rules — the route a planner with a perfect model would choose, and a bound on every
score; ℛ₀ is the exact optimum on the truth with no reserve. Rewards shown are those of the
replanned waypoints (3..n); waypoints 1 and 2 (``reward_collected``) were collected before the
fault by every planner alike.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from gcs_pdm.models.params import ParameterSet
from gcs_pdm.planning.exact import exact_search
from gcs_pdm.planning.local_search import pf_local_search
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.simulator import DEFAULT_DT_S, FAIL_RESERVE, VehicleSimulator
from gcs_pdm.planning.table3_scenario import TABLE3_SIZES, table3_scenario

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Column:
    mean: float
    std: float
    lost: int             # trials whose route the truth could not fly home
    reserve_missed: int   # trials that landed, but inside the landing reserve


@dataclass(frozen=True)
class Table3Row:
    waypoints: int
    optimum: float                # ℛ: exact optimum on the truth, reserve kept
    optimum_route: tuple[int, ...]
    optimum_no_reserve: float     # ℛ₀: exact optimum on the truth without the reserve
    prior: Column
    learned: Column
    stronger: Column
    exact_learned: float          # exact search on the learned model, scored on the truth
    exact_prior: float            # exact search on the prior model, scored on the truth

    @property
    def change_mean_pct(self) -> float:
        return 100.0 * (self.learned.mean - self.prior.mean) / self.prior.mean if self.prior.mean else float("nan")

    @property
    def change_std_pct(self) -> float:
        return 100.0 * (self.learned.std - self.prior.std) / self.prior.std if self.prior.std else float("nan")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["change_mean_pct"] = self.change_mean_pct
        d["change_std_pct"] = self.change_std_pct
        return d


def score_on_truth(truth_sim: VehicleSimulator, routes: Sequence[Sequence[int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(score, lost, reserve_missed) of routes flown on the true vehicle (see the module docstring)."""
    ev = truth_sim.evaluate(routes)
    lost = ev.fail_leg >= 0
    reserve_missed = ev.cause == FAIL_RESERVE
    score = np.where(ev.feasible, ev.reward_reached, 0.0)
    return score, lost, reserve_missed


def _column(scores: np.ndarray, lost: np.ndarray, reserve_missed: np.ndarray) -> Column:
    return Column(mean=float(np.mean(scores)), std=float(np.std(scores)), lost=int(np.sum(lost)),
                  reserve_missed=int(np.sum(reserve_missed)))


def run_table3(truth: ParameterSet, prior: ParameterSet, learned: ParameterSet, *, trials: int = 30,
               particles: int = 30, sizes: Sequence[int] = TABLE3_SIZES, dt_s: float = DEFAULT_DT_S,
               stronger_trials: int | None = None) -> list[Table3Row]:
    rows = []
    for n in sizes:
        sc = table3_scenario(truth, n)
        truth_sim = VehicleSimulator.for_scenario(sc, truth, dt_s=dt_s)
        opt = exact_search(truth_sim)
        no_reserve = dataclasses.replace(sc, limits=dataclasses.replace(sc.limits, landing_reserve_soc=0.0))
        opt0 = exact_search(VehicleSimulator.for_scenario(no_reserve, truth, dt_s=dt_s))
        sims = {"prior": VehicleSimulator.for_scenario(sc, prior, dt_s=dt_s), "learned": VehicleSimulator.for_scenario(sc, learned, dt_s=dt_s)}
        cols = {}
        for key, sim in sims.items():
            routes = [particle_filter(sim, particles=particles, seed=t).route for t in range(trials)]
            cols[key] = _column(*score_on_truth(truth_sim, routes))
        st = trials if stronger_trials is None else stronger_trials
        routes = [pf_local_search(sims["learned"], particles=particles, seed=t).route for t in range(st)]
        cols["stronger"] = _column(*score_on_truth(truth_sim, routes))
        ex = {k: float(score_on_truth(truth_sim, [exact_search(s).route])[0][0]) for k, s in sims.items()}
        rows.append(Table3Row(waypoints=n, optimum=opt.reward, optimum_route=opt.numbers,
                              optimum_no_reserve=opt0.reward, prior=cols["prior"],
                              learned=cols["learned"], stronger=cols["stronger"], exact_learned=ex["learned"],
                              exact_prior=ex["prior"]))
        log.info("table3: %d waypoints done", n)
    return rows


def format_table3(rows: Sequence[Table3Row], *, prior_name: str, learned_name: str, truth_name: str,
                  trials: int, particles: int, collected: float, note: str = "") -> str:
    lines = [
        f"Table III (rebuilt) — PF with K = {particles}, {trials} trials; rewards scored on the true vehicle "
        f"({truth_name}); prior = {prior_name}, learned = {learned_name}",
    ]
    if note:
        lines.append(note)
    lines.append(f"rewards of the replanned waypoints 3..n (waypoints 1, 2 = {collected:g} collected before the fault); "
                 "a route that does not get home with the landing reserve kept scores 0")
    lines.append("ℛ = exact optimum on the truth with the landing reserve, ℛ₀ = without; lost / reserve missed = "
                 "trials (prior / learned / PF+LS)")
    head = (f"{'scenario':<9} {'ℛ':>5} {'ℛ₀':>5}  {'μ_R(σ_R) prior':>15}  {'μ*_R(σ*_R) learned':>18}  "
            f"{'change':>15}  {'PF+LS learned':>13}  {'lost':>8}  {'reserve missed':>14}  {'exact on p/l':>12}")
    lines.append(head)
    lines.append("-" * len(head))
    for r in rows:
        ch_m, ch_s = r.change_mean_pct, r.change_std_pct
        change = f"{ch_m:+.1f}%({ch_s:+.0f}%)" if np.isfinite(ch_s) else f"{ch_m:+.1f}%(n/a)"
        lost = f"{r.prior.lost}/{r.learned.lost}/{r.stronger.lost}"
        missed = f"{r.prior.reserve_missed}/{r.learned.reserve_missed}/{r.stronger.reserve_missed}"
        lines.append(
            f"{str(r.waypoints) + ' wpts':<9} {r.optimum:>5.0f} {r.optimum_no_reserve:>5.0f}  "
            f"{r.prior.mean:>8.1f}({r.prior.std:>5.1f})  {r.learned.mean:>11.1f}({r.learned.std:>5.1f})  "
            f"{change:>15}  {r.stronger.mean:>7.1f}({r.stronger.std:>4.1f})  {lost:>8}  {missed:>14}  "
            f"{f'{r.exact_prior:.0f}/{r.exact_learned:.0f}':>12}")
    return "\n".join(lines)
