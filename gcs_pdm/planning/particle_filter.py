"""The particle-filter planner of the paper's Algorithm 1.

K particles start at the vehicle's position with weight 1/K. In each of D iterations every particle
draws a random permutation τ of its unvisited waypoints and tests ever longer extensions
p_test = {p_k, τ_1..τ_l} (l = 0, 1, …) in the vehicle simulator until one fails; its weight is
Θᵀ{R, −C_h, −C_p} of the last test that did not fail (the failing test itself scores as a failure,
see docs/planning.md); when at least one extension was feasible (l ≥ 1) the particle is extended
by τ_1. After every iteration the best particle is kept (so a deadline returns the best so far),
the weights are normalised and the particles resampled (multinomial).

Reading of line 19–20 ("p* ← p_j"): we keep the tested path that earned particle j its weight,
p_j + τ_1..τ_l, which is feasible by construction and is what that weight measures.

All particles advance together: extension level l of every particle is ONE ``advance`` call and
ONE ``home`` call on the carried prefix states, so a plan costs about 2·D·N kernel calls.
"""
from __future__ import annotations

import logging
from typing import Callable, Sequence

import numpy as np

from gcs_pdm.planning.plan import Plan, better, make_plan
from gcs_pdm.planning.simulator import DEFAULT_THETA, VehicleSimulator

log = logging.getLogger(__name__)

#: weight given to a particle whose objective is not positive (weights must be positive to resample)
WEIGHT_FLOOR = 1e-9


def particle_filter(sim: VehicleSimulator, *, particles: int = 30, iterations: int | None = None,
                    theta: Sequence[float] = DEFAULT_THETA, seed: int | np.random.Generator | None = 0,
                    should_stop: Callable[[], bool] | None = None) -> Plan:
    """Algorithm 1. ``iterations`` D defaults to the number of waypoints (each iteration extends
    a particle by at most one). ``should_stop`` is polled between iterations."""
    if particles < 1:
        raise ValueError(f"particles: must be >= 1, got {particles}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    n = sim.n
    K = int(particles)
    D = n if iterations is None else int(iterations)
    theta = tuple(float(t) for t in theta)
    state = sim.start_state(K)
    paths: list[tuple[int, ...]] = [() for _ in range(K)]
    best: tuple[tuple[int, ...], float, float] | None = None
    done_iterations = 0
    tests = 0
    interrupted = False
    for d in range(D):
        if should_stop is not None and should_stop():
            interrupted = True
            break
        perms = [rng.permutation([w for w in range(n) if w not in set(paths[k])]) for k in range(K)]
        # l = 0: the particle's own path, closed by the landing
        out = sim.home(state)
        tests += K
        weight = np.where(out.feasible, out.objective(theta), -np.inf)
        wreward = np.where(out.feasible, out.reward, -np.inf)
        length = np.zeros(K, dtype=np.int64)
        active = out.feasible.copy()
        cur = state
        first_step = None  # states after τ_1, for the particles that extend
        for level in range(1, n + 1):
            idx = np.flatnonzero(active & np.array([len(p) >= level for p in perms]))
            active[:] = False
            if len(idx) == 0:
                break
            to = np.array([perms[k][level - 1] for k in idx], dtype=np.int64)
            sub = cur.take(idx)
            nxt, ok = sim.advance(sub, to)
            o = sim.home(nxt)
            tests += len(idx)
            feas = ok & o.feasible
            good = idx[feas]
            weight[good] = o.objective(theta)[feas]
            wreward[good] = o.reward[feas]
            length[good] = level
            active[good] = True
            # carry every particle's newest state (only the feasible ones go on)
            cur_x = cur
            cur = _scatter(cur_x, idx, nxt)
            if level == 1:
                first_step = cur
        extend = length >= 1
        for k in np.flatnonzero(np.isfinite(weight)):
            path = paths[k] + tuple(int(w) for w in perms[k][:length[k]])
            # argmax of the weight (line 19), the reward breaking exact ties
            if best is None or better(float(weight[k]), float(wreward[k]), best[2], best[1]):
                best = (path, float(wreward[k]), float(weight[k]))
        if first_step is not None and np.any(extend):
            state = _scatter(state, np.flatnonzero(extend), first_step.take(np.flatnonzero(extend)))
            for k in np.flatnonzero(extend):
                paths[k] = paths[k] + (int(perms[k][0]),)
        done_iterations = d + 1
        # normalise and resample
        w = np.where(np.isfinite(weight), np.maximum(weight, 0.0), 0.0) + WEIGHT_FLOOR
        pick = rng.choice(K, size=K, p=w / w.sum())
        state = state.take(pick)
        paths = [paths[i] for i in pick]
        log.debug("pf: iteration %d, best reward %.1f", d + 1, best[1] if best else float("nan"))
        if all(len(p) == n for p in paths):
            break
    route = best[0] if best is not None else ()
    return make_plan(sim, route, "pf", theta, particles=K, iterations=done_iterations, tests=tests,
                     interrupted=interrupted)


def _scatter(base, idx: np.ndarray, values):
    """``base`` with rows ``idx`` replaced by ``values`` (a FlightState, or the risk simulator's
    RiskState: any dataclass of arrays batched on the first axis; functional)."""
    fields = {}
    for f in type(base).__dataclass_fields__:
        a = getattr(base, f).copy()
        a[idx] = getattr(values, f)
        fields[f] = a
    return type(base)(**fields)
