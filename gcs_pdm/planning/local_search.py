"""Beyond the paper: the particle filter followed by local improvement ("pfls").

The particle filter finds good waypoint *sets* quickly but its random orders leave easy gains:
a cheaper order frees energy for one more waypoint. Local search takes the distinct routes of
three seeded filters, plus the route of a beam search (the exact search keeping its 256 most
promising nodes per level: it finds the other direction round a field, which moves one waypoint
at a time cannot reach), and repeatedly applies the best improving move among

* insert an unvisited waypoint anywhere,
* replace a visited waypoint by an unvisited one (at any position),
* relocate one waypoint, swap two, reverse a segment (2-opt),
* drop one waypoint and insert two unvisited ones (when a waypoint blocks two better ones),
* reverse the whole route and insert one unvisited waypoint,

each neighbourhood flown whole in ONE ``evaluate`` call, until no move improves (reward first,
then the objective Θᵀ{R, −C_h, −C_p}). Every route it returns has been flown whole and is feasible.
The moves and the improvement loop live in :mod:`gcs_pdm.planning.route_moves` (the exact search
warm-starts from them too).
"""
from __future__ import annotations

import logging
from typing import Callable, Sequence

import numpy as np

from gcs_pdm.planning.exact import exact_search
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.plan import Plan, better, make_plan
from gcs_pdm.planning.route_moves import improve, neighbours
from gcs_pdm.planning.simulator import DEFAULT_THETA, VehicleSimulator

__all__ = ["improve", "neighbours", "pf_local_search"]

log = logging.getLogger(__name__)


def pf_local_search(sim: VehicleSimulator, *, particles: int = 30, theta: Sequence[float] = DEFAULT_THETA,
                    seed: int | np.random.Generator | None = 0, starts: int = 3, beam_width: int = 256,
                    should_stop: Callable[[], bool] | None = None) -> Plan:
    """The stronger planner: Algorithm 1 (``starts`` seeded runs) and, with ``beam_width`` > 0, a
    beam search (the exact search keeping that many nodes per level), then local search from each
    distinct route found; the best result wins."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    seeds: list[tuple[int, ...]] = []
    pf_plans = []
    # several short filters give several distinct starting routes for the local search
    for _ in range(max(1, starts)):
        p = particle_filter(sim, particles=particles, theta=theta, seed=rng, should_stop=should_stop)
        pf_plans.append(p)
        if p.route not in seeds:
            seeds.append(p.route)
    beam_reward = None
    if beam_width > 0 and not (should_stop is not None and should_stop()):
        b = exact_search(sim, theta=theta, beam=beam_width, warm_start=False, should_stop=should_stop)
        beam_reward = b.reward
        if b.route not in seeds:
            seeds.append(b.route)
    best = (pf_plans[0].route, pf_plans[0].reward if pf_plans[0].feasible else -1.0,
            pf_plans[0].objective if pf_plans[0].feasible else -np.inf)
    flown = 0
    for s in seeds:
        r, rw, ob, f = improve(sim, s, theta=theta, should_stop=should_stop)
        flown += f
        if better(rw, ob, best[1], best[2]):
            best = (r, rw, ob)
    return make_plan(sim, best[0], "pfls", theta, particles=particles, starts=len(seeds),
                     pf_reward=max(p.reward for p in pf_plans), beam_reward=beam_reward, local_search_routes=flown)
