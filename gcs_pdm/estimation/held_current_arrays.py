"""The held-current Monte Carlo's flight (``prediction._held_current_to_cutoff``, paper packs) in
numpy, for a process that runs without numba's compiler (``NUMBA_DISABLE_JIT``: a replay's first
run on a cold cache, ``gcs_pdm.replay.first_run``).

Interpreted, the compiled kernel steps one pack at a time in Python: a replay's trace (about 20
samples x 256 rows x 720 steps) then takes a minute. Here every row takes each step together as
one array operation. Per row the operations are ``kernel._simulate_pack_block``'s single-step path
(``kernel._pack_step``), in its order, on the same values, so the numbers are the compiled ones bit
for bit (tests/test_held_current_arrays.py): IEEE ``+ - * /`` are exact per element, and ``exp`` is
the C library's, as compiled code calls it, unless numpy has its own vector ``exp`` (AVX-512), which
is then not used.

Only what the held-current prediction flies is covered: one interval length ``dt`` for every step,
not cut into sub-steps (``dt <= max_dt``), a constant current per row and one ambient.
``applies`` says whether a call is such; the caller flies anything else through the kernel.
"""
from __future__ import annotations

import math

import numpy as np

from gcs_pdm.models import kernel as k


def _numpy_exp_is_libm() -> bool:
    """numpy's float64 ``exp`` is the C library's unless numpy dispatched its AVX-512 loop."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # another numpy layout: do not trust it
        return False
    return not (features.get("AVX512F") or features.get("AVX512_SKX"))


if _numpy_exp_is_libm():
    _exp = np.exp
else:
    def _exp(a: np.ndarray) -> np.ndarray:
        return np.fromiter(map(math.exp, a.tolist()), dtype=np.float64, count=a.size)


def applies(dt: np.ndarray, max_dt: float) -> bool:
    """Whether ``fly`` covers a flight on ``dt``: one length, > 0 and not above ``max_dt``."""
    dt = np.asarray(dt, dtype=np.float64)
    return dt.size > 0 and bool(np.all(dt == dt[0])) and 0.0 < float(dt[0]) <= max_dt


def fly(params: np.ndarray, state: np.ndarray, dt: np.ndarray, current: np.ndarray, cutoff_v: np.ndarray,
        ambient_c: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows of paper packs (``params`` (R, 12), ``state`` (R, 4)) at a held ``current`` (R,) over
    ``dt`` (``applies``): (first step below ``cutoff_v`` or empty, -1 if none; peak temperature up
    to and including it, NaN once a temperature is NaN), as ``prediction._held_current_to_cutoff``."""
    dt = np.asarray(dt, dtype=np.float64)
    n_rows, n_steps = params.shape[0], dt.size
    end_step = np.full(n_rows, -1)
    peak = np.full(n_rows, -np.inf)
    h = float(dt[0])  # _substeps: one sub-step of dt / 1
    rows = np.arange(n_rows)
    p = np.ascontiguousarray(params.T)  # one vector per parameter, as the kernel's lanes
    x = np.array(state, dtype=np.float64).T.copy()
    cur = np.array(current, dtype=np.float64)
    cutoff = np.array(cutoff_v, dtype=np.float64)
    tau_s = p[k.I_RS] * p[k.I_CS]
    decay_s = _exp(-h / tau_s)  # kernel._fixed_decays
    decay_t = _exp(-h * p[k.I_H] / p[k.I_CT])
    v = x[k.S_QB] / p[k.I_CB] - x[k.S_QCP] / p[k.I_CCP] - x[k.S_QS] / p[k.I_CS]
    top = np.full(n_rows, -np.inf)
    for step in range(n_steps):
        i_b = cur + v / p[k.I_RP]
        soc_mid = 1.0 - (p[k.I_QMAX] - (x[k.S_QB] - 0.5 * i_b * h)) / p[k.I_CMAX]
        r_cp = p[k.I_RCP0] + p[k.I_RCP1] * _exp(p[k.I_RCP2] * (1.0 - soc_mid))
        tau_cp = r_cp * p[k.I_CCP]
        decay_cp = _exp(-h / (r_cp * p[k.I_CCP]))
        x[k.S_QS] = i_b * tau_s + (x[k.S_QS] - i_b * tau_s) * decay_s
        x[k.S_QCP] = i_b * tau_cp + (x[k.S_QCP] - i_b * tau_cp) * decay_cp
        x[k.S_QB] -= i_b * h
        t_inf = ambient_c + (p[k.I_RS] + r_cp) * cur * cur / p[k.I_H]
        x[k.S_T] = t_inf + (x[k.S_T] - t_inf) * decay_t
        v = x[k.S_QB] / p[k.I_CB] - x[k.S_QCP] / p[k.I_CCP] - x[k.S_QS] / p[k.I_CS]
        soc = 1.0 - (p[k.I_QMAX] - x[k.S_QB]) / p[k.I_CMAX]
        temp = x[k.S_T]
        # the running peak: NaN spreads, as in the compiled loop (``elif t > top``)
        top = np.where(np.isnan(temp) | np.isnan(top), np.nan, np.where(temp > top, temp, top))
        ended = (v < cutoff) | (soc <= 0.0)
        if ended.any():
            end_step[rows[ended]] = step
            peak[rows[ended]] = top[ended]
            keep = ~ended
            rows, p, x, cur, cutoff = rows[keep], p[:, keep], x[:, keep], cur[keep], cutoff[keep]
            tau_s, decay_s, decay_t, v, top = tau_s[keep], decay_s[keep], decay_t[keep], v[keep], top[keep]
            if rows.size == 0:
                break
    peak[rows] = top
    return end_step, peak
