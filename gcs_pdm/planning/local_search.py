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
"""
from __future__ import annotations

import logging
from typing import Callable, Sequence

import numpy as np

from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.plan import Plan, better, make_plan, rank
from gcs_pdm.planning.simulator import DEFAULT_THETA, VehicleSimulator

log = logging.getLogger(__name__)


def neighbours(route: tuple[int, ...], n: int, *, wide: bool = True) -> list[tuple[int, ...]]:
    """All routes one move away from ``route`` over waypoints 0..n-1 (distinct, deduplicated).
    ``wide=False`` leaves out the drop-one-add-two moves (the largest neighbourhood)."""
    r = list(route)
    unvisited = [w for w in range(n) if w not in set(r)]
    out: set[tuple[int, ...]] = set()
    L = len(r)
    for u in unvisited:
        for i in range(L + 1):
            out.add(tuple(r[:i] + [u] + r[i:]))
    for i in range(L):
        rest = r[:i] + r[i + 1:]
        for u in unvisited:
            for j in range(L):
                out.add(tuple(rest[:j] + [u] + rest[j:]))
        for j in range(L):
            if j != i:
                out.add(tuple(rest[:j] + [r[i]] + rest[j:]))
        for j in range(i + 1, L):
            s = r.copy()
            s[i], s[j] = s[j], s[i]
            out.add(tuple(s))
            out.add(tuple(r[:i] + r[i:j + 1][::-1] + r[j + 1:]))
        if not wide:
            continue
        for a in range(len(unvisited)):
            for b in range(len(unvisited)):
                if a != b:
                    for j in range(L):
                        out.add(tuple(rest[:j] + [unvisited[a]] + rest[j:] + [unvisited[b]]))
                        out.add(tuple(rest[:j] + [unvisited[a], unvisited[b]] + rest[j:]))
    if wide:
        # fly it the other way round with one more waypoint (direction matters: climbs and the
        # string that tires first differ)
        back = r[::-1]
        for u in unvisited:
            for i in range(L + 1):
                out.add(tuple(back[:i] + [u] + back[i:]))
    out.discard(tuple(r))
    return list(out)


def improve(sim: VehicleSimulator, route: Sequence[int], *, theta: Sequence[float] = DEFAULT_THETA,
            max_rounds: int = 50, should_stop: Callable[[], bool] | None = None) -> tuple[tuple[int, ...], float, float, int]:
    """Best-improvement local search from a feasible (or empty) route: (route, reward, objective, routes flown)."""
    cur = tuple(int(v) for v in route)
    ev = sim.evaluate([cur])
    cur_r = float(ev.reward[0]) if ev.feasible[0] else -1.0
    cur_o = float(ev.objective(theta)[0]) if ev.feasible[0] else -np.inf
    flown = 1
    rewards = sim.rewards
    wide = False
    for _ in range(max_rounds):
        if should_stop is not None and should_stop():
            break
        # a move that loses reward can never win (reward ranks first): do not fly it
        cands = [c for c in neighbours(cur, sim.n, wide=wide) if rewards[list(c)].sum() >= cur_r - 1e-9]
        if cands:
            ev = sim.evaluate(cands)
            flown += len(cands)
            obj = np.where(ev.feasible, ev.objective(theta), -np.inf)
            rew = np.where(ev.feasible, ev.reward, -1.0)
            i = rank(rew, obj)
            if better(float(rew[i]), float(obj[i]), cur_r, cur_o):
                cur, cur_r, cur_o = cands[i], float(rew[i]), float(obj[i])
                wide = False
                continue
        if wide:
            break
        # the small moves are exhausted: try the wide neighbourhood before giving up
        wide = True
    return cur, cur_r, cur_o, flown


def pf_local_search(sim: VehicleSimulator, *, particles: int = 30, theta: Sequence[float] = DEFAULT_THETA,
                    seed: int | np.random.Generator | None = 0, starts: int = 3, beam_width: int = 256,
                    should_stop: Callable[[], bool] | None = None) -> Plan:
    """The stronger planner: Algorithm 1 (``starts`` seeded runs) and, with ``beam_width`` > 0, a
    beam search (the exact search keeping that many nodes per level), then local search from each
    distinct route found; the best result wins."""
    from gcs_pdm.planning.exact import exact_search

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
