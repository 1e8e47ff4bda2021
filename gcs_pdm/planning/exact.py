"""Exact search (the paper's deterministic column ℛ) and the brute force that checks it.

The search is a level-synchronous branch and bound over ordered waypoint subsets. A node is a
prefix route flown from the start (its state carried, :class:`FlightState`); every node that can
still get home is itself a candidate answer. Level L holds the prefixes of L waypoints, and all
their one-waypoint extensions are flown in ONE kernel call, then all the returns home in another.

Pruning, and the assumptions that make it exact (the brute force checks them in the tests):

* failure — a prefix that cannot get home is dropped with all its extensions: flying further
  before going home never leaves the vehicle better off (more charge drawn, more heat);
* dominance — of two prefixes visiting the same set and ending at the same waypoint, one whose
  state is no worse in every respect (charge, polarisation, temperatures, peaks, energy) can do all
  the other can, so the other is dropped;
* bound — a prefix whose reward plus every unvisited reward cannot beat the best complete route
  is dropped (this one is always valid).

The answer maximises reward; among equal rewards, the objective Θᵀ{R, −C_h, −C_p}.
"""
from __future__ import annotations

import itertools
import logging
from typing import Callable, Sequence

import numpy as np

from gcs_pdm.models import kernel
from gcs_pdm.planning.plan import Plan, better, make_plan, rank
from gcs_pdm.planning.simulator import DEFAULT_THETA, FlightState, Outcome, VehicleSimulator

log = logging.getLogger(__name__)


def _goodness(state: FlightState, out: Outcome) -> np.ndarray:
    """Per node, a vector in which larger is better in every component (for dominance)."""
    x = state.x
    return np.concatenate([
        x[:, :, kernel.S_QB], -x[:, :, kernel.S_QCP], -x[:, :, kernel.S_QS], -x[:, :, kernel.S_T],
        -state.motor_temp, -state.peak_pack_c[:, None], -state.peak_motor_c[:, None],
        -state.energy_j[:, None], -out.health_cost[:, None],
    ], axis=1)


def _pareto_keep(keys: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Indices of the nodes not dominated by another node with the same key."""
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    bounds = np.flatnonzero(np.diff(ks)) + 1
    keep: list[np.ndarray] = []
    for grp in np.split(order, bounds):
        if len(grp) == 1:
            keep.append(grp)
            continue
        g = good[grp]
        ge = np.all(g[:, None, :] >= g[None, :, :] - 1e-12, axis=2)  # ge[i, j]: i at least as good as j
        np.fill_diagonal(ge, False)
        # j is dropped when some i is at least as good; of exact ties keep the first
        dominated = np.zeros(len(grp), dtype=bool)
        for j in range(len(grp)):
            for i in np.flatnonzero(ge[:, j]):
                if not dominated[i] and (not ge[j, i] or i < j):
                    dominated[j] = True
                    break
        keep.append(grp[~dominated])
    return np.sort(np.concatenate(keep))


def exact_search(sim: VehicleSimulator, *, theta: Sequence[float] = DEFAULT_THETA, dominance: bool = True,
                 should_stop: Callable[[], bool] | None = None) -> Plan:
    """The reward-optimal route (ties broken by the objective), proven under the assumptions above."""
    n = sim.n
    rewards = sim.rewards[:n]
    root = sim.start_state(1)
    root_out = sim.home(root)
    best_route: tuple[int, ...] = ()
    best_r, best_o = (float(root_out.reward[0]), float(root_out.objective(theta)[0])) if root_out.feasible[0] \
        else (-1.0, -np.inf)
    frontier = root
    routes: list[tuple[int, ...]] = [()]
    masks = np.zeros(1, dtype=np.int64)
    if not root_out.feasible[0]:
        log.warning("exact: the vehicle cannot get home even directly (%s)", root_out.cause[0])
        frontier = root.take(np.zeros(0, dtype=np.int64))
        routes = []
        masks = masks[:0]
    nodes = 0
    rows = 0
    interrupted = False
    level = 0
    while len(frontier):
        if should_stop is not None and should_stop():
            interrupted = True
            break
        level += 1
        # every unvisited waypoint of every frontier node whose bound can still win
        visited = (masks[:, None] >> np.arange(n)[None, :]) & 1
        left = np.where(visited == 0, rewards[None, :], 0.0).sum(axis=1)
        alive = frontier.reward + left >= best_r - 1e-9
        parent, child = np.nonzero((visited == 0) & alive[:, None])
        if len(parent) == 0:
            break
        st, ok = sim.advance(frontier.take(parent), child)
        parent, child, st = parent[ok], child[ok], st.take(np.flatnonzero(ok))
        out = sim.home(st)
        rows += len(ok) + len(st)
        feas = out.feasible
        parent, child, st = parent[feas], child[feas], st.take(np.flatnonzero(feas))
        out = Outcome(*(getattr(out, f)[feas] for f in Outcome.__dataclass_fields__))
        if len(parent) == 0:
            break
        new_masks = masks[parent] | (1 << child)
        if dominance:
            keep = _pareto_keep(new_masks * (n + 1) + child, _goodness(st, out))
            parent, child, st, new_masks = parent[keep], child[keep], st.take(keep), new_masks[keep]
            out = Outcome(*(getattr(out, f)[keep] for f in Outcome.__dataclass_fields__))
        obj = out.objective(theta)
        i = rank(out.reward, obj)
        if better(float(out.reward[i]), float(obj[i]), best_r, best_o):
            best_r, best_o = float(out.reward[i]), float(obj[i])
            best_route = routes[parent[i]] + (int(child[i]),)
        routes = [routes[p] + (int(c),) for p, c in zip(parent, child)]
        frontier, masks = st, new_masks
        nodes += len(parent)
        log.debug("exact: level %d, %d nodes, best reward %.1f", level, len(parent), best_r)
    return make_plan(sim, best_route, "exact", theta, nodes=nodes, simulated_rows=rows, levels=level,
                     proven_optimal=not interrupted, interrupted=interrupted)


def brute_force(sim: VehicleSimulator, *, theta: Sequence[float] = DEFAULT_THETA, max_routes: int = 2_000_000,
                chunk: int = 20_000) -> Plan:
    """Every ordered subset flown whole from the start (no carried states, no pruning)."""
    n = sim.n
    total = sum(_perm_count(n, k) for k in range(n + 1))
    if total > max_routes:
        raise ValueError(f"brute force over {n} waypoints is {total} routes (> max_routes={max_routes})")
    best = ((), -1.0, -np.inf)
    batch: list[tuple[int, ...]] = []

    def flush() -> None:
        nonlocal best, batch
        if not batch:
            return
        ev = sim.evaluate(batch)
        obj = ev.objective(theta)
        i = rank(np.where(ev.feasible, ev.reward, -1.0), np.where(ev.feasible, obj, -np.inf))
        if ev.feasible[i] and better(float(ev.reward[i]), float(obj[i]), best[1], best[2]):
            best = (batch[i], float(ev.reward[i]), float(obj[i]))
        batch = []

    for k in range(n + 1):
        for r in itertools.permutations(range(n), k):
            batch.append(r)
            if len(batch) >= chunk:
                flush()
    flush()
    return make_plan(sim, best[0], "brute_force", theta, routes=total)


def _perm_count(n: int, k: int) -> int:
    out = 1
    for i in range(k):
        out *= n - i
    return out
