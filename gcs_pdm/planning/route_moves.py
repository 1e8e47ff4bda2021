"""Route moves and best-improvement local search, shared by the stronger planner
(:mod:`gcs_pdm.planning.local_search`) and the exact search's warm start (:mod:`gcs_pdm.planning.exact`).

A module of its own so neither of those imports the other.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from gcs_pdm.planning.plan import better, rank
from gcs_pdm.planning.simulator import DEFAULT_THETA, VehicleSimulator


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
