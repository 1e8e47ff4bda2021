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
* reach — a waypoint that a prefix cannot visit and still get home from is not tried after any
  extension of that prefix either (a detour before it never helps), so each node carries the set
  of waypoints it may still add: its parent's other feasible extensions;
* bound — a prefix whose reward plus the rewards it may still add cannot beat the best route found
  (seeded by a local search), or can only tie it with no better objective bound (costs so far are a
  lower bound on the final costs), is dropped.

The answer maximises reward; among equal rewards, the objective Θᵀ{R, −C_h, −C_p}.
"""
from __future__ import annotations

import itertools
import logging
from typing import Callable, Sequence

import numpy as np

from gcs_pdm.models import kernel
from gcs_pdm.planning.plan import Plan, better, make_plan, rank
from gcs_pdm.planning.route_moves import improve
from gcs_pdm.planning.simulator import DEFAULT_THETA, FAILURE_NAMES, FlightState, Outcome, VehicleSimulator

log = logging.getLogger(__name__)


def _goodness(state: FlightState, out: Outcome) -> np.ndarray:
    """Per node, a vector in which larger is better in every component (for dominance). A risk
    state carries every draw (``x`` (B, S, 4, 4)): each draw's components count, and a draw that
    failed never dominates one that did not."""
    x, B = state.x, len(state)

    def flat(a):
        return np.asarray(a).reshape(B, -1)

    parts = [flat(x[..., kernel.S_QB]), -flat(x[..., kernel.S_QCP]), -flat(x[..., kernel.S_QS]),
             -flat(x[..., kernel.S_T]), -flat(state.motor_temp), -flat(state.peak_pack_c), -flat(state.peak_motor_c),
             -flat(state.energy_j), -out.health_cost[:, None]]
    failed = getattr(state, "failed", None)
    if failed is not None:
        parts.append(-flat(failed).astype(np.float64))
    return np.concatenate(parts, axis=1)


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
                 warm_start: bool = True, beam: int | None = None,
                 should_stop: Callable[[], bool] | None = None) -> Plan:
    """The reward-optimal route (ties broken by the objective), proven under the assumptions above.

    ``warm_start`` seeds the incumbent with a local search from the empty route, so the bounds
    prune from the first level on. ``beam`` (a heuristic, not exact) keeps only that many nodes per
    level, those with the most reward plus reachable reward, then the best objective."""
    n = sim.n
    rewards = sim.rewards[:n]
    theta = tuple(float(t) for t in theta)
    root = sim.start_state(1)
    root_out = sim.home(root)
    best_route: tuple[int, ...] = ()
    best_r, best_o = (float(root_out.reward[0]), float(root_out.objective(theta)[0])) if root_out.feasible[0] \
        else (-1.0, -np.inf)
    warm_routes = 0
    if warm_start and root_out.feasible[0]:
        r, rw, ob, warm_routes = improve(sim, (), theta=theta, should_stop=should_stop)
        if better(rw, ob, best_r, best_o):
            best_route, best_r, best_o = r, rw, ob
    frontier = root
    routes: list[tuple[int, ...]] = [()]
    masks = np.zeros(1, dtype=np.int64)
    reach = np.full(1, (1 << n) - 1, dtype=np.int64)  # waypoints a node may still add
    if not root_out.feasible[0]:
        log.warning("exact: the vehicle cannot get home even directly (%s)", FAILURE_NAMES[int(root_out.cause[0])])
        frontier = root.take(np.zeros(0, dtype=np.int64))
        routes, masks, reach = [], masks[:0], reach[:0]
    # the objective bound needs costs that only grow along a route, i.e. non-negative cost weights
    cost_bound = theta[1] >= 0 and theta[2] >= 0
    bits = np.arange(n)
    nodes = 0
    rows = 0
    interrupted = False
    level = 0
    tol = 1e-9
    while len(frontier):
        if should_stop is not None and should_stop():
            interrupted = True
            break
        level += 1
        can = ((reach[:, None] >> bits[None, :]) & 1).astype(bool)
        bound_r = frontier.reward + (can * rewards[None, :]).sum(axis=1)
        alive = bound_r > best_r + tol
        if cost_bound:
            c_h, c_p = sim.cost_lower_bound(frontier)
            bound_o = theta[0] * bound_r - theta[1] * c_h - theta[2] * c_p
            alive |= (bound_r >= best_r - tol) & (bound_o > best_o + tol)
        else:
            alive |= bound_r >= best_r - tol
        parent, child = np.nonzero(can & alive[:, None])
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
        # what a child may still add: its parent's other feasible children (a waypoint the parent
        # could not visit and get home from cannot be visited after a detour either)
        feasible_children = np.zeros(len(frontier), dtype=np.int64)
        np.bitwise_or.at(feasible_children, parent, np.left_shift(1, child))
        new_reach = feasible_children[parent] & ~np.left_shift(1, child)
        new_masks = masks[parent] | np.left_shift(1, child)
        if dominance:
            keep = _pareto_keep(new_masks * (n + 1) + child, _goodness(st, out))
            parent, child, st = parent[keep], child[keep], st.take(keep)
            new_masks, new_reach = new_masks[keep], new_reach[keep]
            out = Outcome(*(getattr(out, f)[keep] for f in Outcome.__dataclass_fields__))
        obj = out.objective(theta)
        if beam is not None and len(parent) > beam:
            reach_r = (((new_reach[:, None] >> bits[None, :]) & 1) * rewards[None, :]).sum(axis=1)
            top = np.lexsort((-obj, -(out.reward + reach_r)))[:beam]
            parent, child, st, new_masks, new_reach = parent[top], child[top], st.take(top), new_masks[top], new_reach[top]
            out = Outcome(*(getattr(out, f)[top] for f in Outcome.__dataclass_fields__))
            obj = obj[top]
        i = rank(out.reward, obj)
        if better(float(out.reward[i]), float(obj[i]), best_r, best_o):
            best_r, best_o = float(out.reward[i]), float(obj[i])
            best_route = routes[parent[i]] + (int(child[i]),)
        routes = [routes[p] + (int(c),) for p, c in zip(parent, child)]
        frontier, masks, reach = st, new_masks, new_reach
        nodes += len(parent)
        log.debug("exact: level %d, %d nodes, best reward %.1f", level, len(parent), best_r)
    return make_plan(sim, best_route, "exact" if beam is None else "beam", theta, nodes=nodes, simulated_rows=rows,
                     levels=level, warm_start_routes=warm_routes, proven_optimal=not interrupted and beam is None,
                     interrupted=interrupted)


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
