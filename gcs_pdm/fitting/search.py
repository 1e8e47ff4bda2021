"""The paper's search: simulated annealing from random starts, then Levenberg–Marquardt from each.

**Batched annealing** (:func:`anneal`). All starts run as parallel chains. Every generation each
chain proposes ``proposals`` Gaussian moves in the unit cube (reflected at the bounds, step shrinking
with the temperature); the whole population — chains × proposals — is ONE batched kernel call per
flight. Each chain takes its best proposal through the Metropolis test on the log of the mean
squared error (scale-free: a temperature of 0.1 accepts a 10 % worse error with probability 1/e),
and the temperature falls geometrically from ``t_start`` to ``t_end``. We chose this over
``scipy.optimize.dual_annealing``, whose callback evaluates one vector at a time: the batched kernel
is ~20× faster per vector at a population of 40 than at 1 (call overhead and Python per step), so
the same evaluation budget takes a fraction of the wall time (docs/fitting.md has the figures).

**Levenberg–Marquardt** (:func:`levenberg_marquardt`): ``scipy.optimize.least_squares(method="lm")``
on the residual vector, in ``z`` with u = (1 + sin z) / 2 (MINUIT's bounded transform, so the
unconstrained LM stays inside the expected ranges), with a batched forward-difference Jacobian: the
d shifted vectors are one kernel call per flight.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

log = logging.getLogger(__name__)


class FitCancelled(RuntimeError):
    """Raised when ``should_stop`` asked the fit to stop."""


@dataclass(frozen=True)
class SearchSettings:
    starts: int = 10
    sa_generations: int = 120
    sa_proposals: int = 4
    sa_t_start: float = 0.3
    sa_t_end: float = 1e-3
    sa_step_start: float = 0.25
    sa_step_end: float = 0.01
    lm_max_nfev: int = 30
    lm_fd_step: float = 1e-6
    seed: int = 0

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class AnnealResult:
    best_u: np.ndarray      # (starts, d) best point of each chain
    best_mse: np.ndarray    # (starts,)
    start_u: np.ndarray     # (starts, d)
    evaluations: int


def _reflect(u: np.ndarray) -> np.ndarray:
    u = np.abs(u)
    u = np.where(u > 1.0, 2.0 - u, u)
    return np.clip(u, 0.0, 1.0)


def anneal(cost: Callable[[np.ndarray], np.ndarray], dim: int, settings: SearchSettings, rng: np.random.Generator,
           *, progress: Callable[[float], None] | None = None, should_stop: Callable[[], bool] | None = None,
           ) -> AnnealResult:
    """Batched simulated annealing of ``cost`` (U (N, dim) -> (N,) mean squared error) in [0, 1]^dim."""
    s = settings
    S, K, G = s.starts, s.sa_proposals, s.sa_generations
    start = rng.random((S, dim))
    cur = start.copy()
    e_cur = np.log(np.maximum(cost(cur), 1e-300))
    best, e_best = cur.copy(), e_cur.copy()
    evaluations = S
    for g in range(G):
        if should_stop is not None and should_stop():
            raise FitCancelled("stopped during annealing")
        frac = g / max(G - 1, 1)
        temp = s.sa_t_start * (s.sa_t_end / s.sa_t_start) ** frac
        step = s.sa_step_start * (s.sa_step_end / s.sa_step_start) ** frac
        prop = _reflect(cur[:, None, :] + step * rng.standard_normal((S, K, dim)))
        e = np.log(np.maximum(cost(prop.reshape(S * K, dim)), 1e-300)).reshape(S, K)
        evaluations += S * K
        k = np.argmin(e, axis=1)
        e_new = e[np.arange(S), k]
        u_new = prop[np.arange(S), k]
        accept = (e_new < e_cur) | (rng.random(S) < np.exp(-np.maximum(e_new - e_cur, 0.0) / temp))
        cur[accept], e_cur[accept] = u_new[accept], e_new[accept]
        better = e_cur < e_best
        best[better], e_best[better] = cur[better], e_cur[better]
        if progress is not None:
            progress((g + 1) / G)
    return AnnealResult(best_u=best, best_mse=np.exp(e_best), start_u=start, evaluations=evaluations)


def _u_of_z(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.sin(z))


def _z_of_u(u: np.ndarray) -> np.ndarray:
    # keep off the exact bounds, where the transform's derivative vanishes
    return np.arcsin(np.clip(2.0 * np.asarray(u) - 1.0, -0.999, 0.999))


@dataclass
class LMResult:
    u: np.ndarray
    mse: float
    nfev: int
    njev: int
    status: int
    message: str


#: columns of the Jacobian a problem computes itself: (their indices among the shared unknowns, a function
#: u (n,) -> (residuals (m,), derivatives (m, k) with respect to those coordinates of u))
PartialJacobian = tuple[np.ndarray, Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]]


def levenberg_marquardt(residuals: Callable[[np.ndarray], np.ndarray], u0: np.ndarray, settings: SearchSettings,
                        *, shared: int | None = None, blocks: list[slice] | None = None,
                        partial: PartialJacobian | None = None) -> LMResult:
    """Refine ``u0`` with MINPACK's LM; ``residuals`` maps U (N, n) -> (N, m) in one batched call.

    Block-separable unknowns: with ``shared=d`` and ``blocks`` (one row slice per extra unknown), the
    coordinates after the first d are per-block unknowns (e.g. each flight's initial SoC) that move
    only their own rows. One shifted vector then moves all of them at once and gives every block's
    derivative, so the Jacobian costs d + 1 vectors, not n.

    ``partial``: columns the problem differentiates more cheaply than one shifted vector each (the
    extended variant's OCV knots, ``ExtendedPackProblem.ocv_jacobian``); the others are forward
    differences as above.
    """
    n = u0.size
    d = n if shared is None else int(shared)
    extra = n - d
    if extra and (blocks is None or len(blocks) != extra):
        raise ValueError(f"blocks: need one row slice per extra unknown ({extra})")
    h = settings.lm_fd_step
    own = np.zeros(0, dtype=int) if partial is None else np.asarray(partial[0], dtype=int)
    fd_cols = np.setdiff1d(np.arange(d), own)
    cache: dict[bytes, np.ndarray] = {}

    def fun(z: np.ndarray) -> np.ndarray:
        r = residuals(_u_of_z(z)[None])[0]
        cache.clear()
        cache[z.tobytes()] = r
        return r

    def jac(z: np.ndarray) -> np.ndarray:
        r0 = cache.get(z.tobytes())
        J_own = None
        if own.size:
            r_own, J_own = partial[1](_u_of_z(z))
            r0 = r_own if r0 is None else r0
        nd = fd_cols.size
        k = nd + (1 if extra else 0)
        shifted = np.tile(z, (k + (r0 is None), 1))
        shifted[np.arange(nd), fd_cols] += h
        if extra:
            shifted[nd, d:] += h
        R = residuals(_u_of_z(shifted)) if shifted.shape[0] else np.zeros((0, r0.size))
        if r0 is None:
            r0 = R[-1]
        J = np.zeros((r0.size, n))
        J[:, fd_cols] = ((R[:nd] - r0) / h).T
        if J_own is not None:
            # chain rule through u = (1 + sin z) / 2
            J[:, own] = J_own * (0.5 * np.cos(z[own]))
        if extra:
            col = (R[nd] - r0) / h
            for i, rows in enumerate(blocks):
                J[rows, d + i] = col[rows]
        return J

    z0 = _z_of_u(u0)
    res = least_squares(fun, z0, jac=jac, method="lm", max_nfev=settings.lm_max_nfev, x_scale=1.0)
    u = _u_of_z(res.x)
    return LMResult(u=u, mse=float(np.mean(res.fun ** 2)), nfev=int(res.nfev), njev=int(res.njev or 0),
                    status=int(res.status), message=str(res.message))


def levenberg_marquardt_subset(residuals: Callable[[np.ndarray], np.ndarray], u: np.ndarray, cols: np.ndarray,
                               settings: SearchSettings, *, partial: Callable | None = None) -> LMResult:
    """LM over the coordinates ``cols`` of ``u`` only, the others held; ``partial`` (optional): u (n,) ->
    (residuals, derivatives with respect to exactly those coordinates), so no shifted vector is simulated.
    The result's ``u`` is the whole point."""
    u = np.asarray(u, dtype=np.float64)
    cols = np.asarray(cols, dtype=int)

    def embed(U_sub: np.ndarray) -> np.ndarray:
        U = np.tile(u, (U_sub.shape[0], 1))
        U[:, cols] = U_sub
        return U

    own = None if partial is None else (np.arange(cols.size), lambda us: partial(embed(us[None])[0]))
    res = levenberg_marquardt(lambda U_sub: residuals(embed(U_sub)), u[cols], settings, partial=own)
    res.u = embed(res.u[None])[0]
    return res
