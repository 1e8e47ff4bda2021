"""The one simulation kernel: battery equivalent circuit (eqs. 1–6) and lumped thermal model (eq. 7).

Every simulation in gcs-pdm — fitting residuals, the estimator's predictions, the planner's route
simulations and the simulated vehicle's truth — runs through the compiled step functions here.
They are batched: N parameter vectors (or particles, or routes) advance together over a profile of
n samples with possibly uneven time steps.

Time convention (zero-order hold, backward): sample k sits at time t_k, ``dt[k] = t_k - t_{k-1}``
(``dt[0]`` is normally 0), and ``current[k]`` is the current that flowed over (t_{k-1}, t_k]. The
outputs at k are the state after that interval, so a voltage sample and the current measured with
it belong together, as in a flight log.

Integration: over one interval the circuit is linear once the slowly varying terms (R_cp(SoC), taken
at the interval's mid-point charge, and the parasitic current, which moves by parts per million per
second, taken at its start) are frozen. Each R–C pair then has an exact exponential step, and so does the thermal model, so the
scheme is unconditionally stable and exact for the linear parts at any step length: a 1 s log step
over a 0.8 s R_s–C_s time constant is no problem. Intervals longer than ``max_dt`` are cut into
equal sub-steps (at most ``MAX_SUBSTEPS``) so the frozen terms stay accurate across log gaps.

Layouts (all float64):
  pack parameters ``PACK_PARAMS`` (12), pack state ``PACK_STATE`` (4), motor parameters
  ``MOTOR_PARAMS`` (5). Inputs shaped (n,) are shared by every vector; (N, n) is per vector.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from gcs_pdm.models.variants import MODEL_VARIANTS  # noqa: F401 (re-exported: kernel.MODEL_VARIANTS)
from gcs_pdm.models.lane_math import asinh_row, exp_row

PACK_PARAMS: tuple[str, ...] = (
    "R_s", "R_p", "R_cp0", "R_cp1", "R_cp2", "C_s", "C_b", "C_cp", "q_max", "C_max", "C_t", "h",
)
PACK_STATE: tuple[str, ...] = ("q_b", "q_cp", "q_s", "T")
MOTOR_PARAMS: tuple[str, ...] = ("R_w", "I_0", "P_iron", "C_t", "h")

N_PACK_PARAMS = len(PACK_PARAMS)
N_PACK_STATE = len(PACK_STATE)
N_MOTOR_PARAMS = len(MOTOR_PARAMS)

(I_RS, I_RP, I_RCP0, I_RCP1, I_RCP2, I_CS, I_CB, I_CCP, I_QMAX, I_CMAX, I_CT, I_H) = range(N_PACK_PARAMS)
(S_QB, S_QCP, S_QS, S_T) = range(N_PACK_STATE)
(M_RW, M_I0, M_PIRON, M_CT, M_H) = range(N_MOTOR_PARAMS)

#: default longest interval integrated in one exponential step, s
DEFAULT_MAX_DT = 10.0
#: most sub-steps of one interval: longer intervals get longer sub-steps (see ``_pack_advance``)
MAX_SUBSTEPS = 360

_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


# ---- the step --------------------------------------------------------------------------------------

# The step functions index a parameter table ``p`` (rows of PACK_PARAMS or MOTOR_PARAMS) and a
# state table ``x`` (rows of PACK_STATE) by row instead of taking row views: in numba a view puts
# two atomic reference-count calls into a driver's compiled inner loop.
# ``_pack_advance``/``_thermal_advance`` keep the one-row form for single callers (the estimator).

@njit(inline="always", **_JIT)
def _soc(p, i, q_b):
    return 1.0 - (p[i, I_QMAX] - q_b) / p[i, I_CMAX]


@njit(inline="always", **_JIT)
def _r_cp(p, i, soc):
    return p[i, I_RCP0] + p[i, I_RCP1] * math.exp(p[i, I_RCP2] * (1.0 - soc))


@njit(inline="always", **_JIT)
def _terminal_voltage(p, i, x, r):
    return x[r, S_QB] / p[i, I_CB] - x[r, S_QCP] / p[i, I_CCP] - x[r, S_QS] / p[i, I_CS]


@njit(inline="always", **_JIT)
def _substeps(dt, max_dt):
    """Sub-steps of an interval ``dt`` > 0 and their length."""
    n_sub = 1
    if dt > max_dt:
        # capped: work bounded by samples, not by the time span (a 49.7-day log gap cost 0.25 s).
        # The R–C and thermal steps are exact at any length; only the frozen R_cp and parasitic
        # terms want short steps, and past MAX_SUBSTEPS · max_dt the held input is a guess anyway
        n_sub = min(int(math.ceil(dt / max_dt)), MAX_SUBSTEPS)
    return n_sub, dt / n_sub


@njit(inline="always", **_JIT)
def _fixed_decays(p, i, h, tau_s):
    """The R_s–C_s and thermal decay factors of a step of length ``h``: they depend on the
    parameters and ``h`` only, so a driver whose steps repeat one length computes them once."""
    return math.exp(-h / tau_s), math.exp(-h * p[i, I_H] / p[i, I_CT])


@njit(inline="always", **_JIT)
def _pack_step(p, i, x, r, current, ambient, h, tau_s, decay_s, decay_t, v):
    """One exact exponential step of length ``h`` of pack state row ``x[r]`` (in place), parameters
    ``p[i]``, at constant terminal current; ``v`` = ``_terminal_voltage(p, i, x, r)`` at the step's
    start (drivers carry it from the previous step's output instead of dividing again)."""
    # parasitic branch across the terminals (eq. 5): i_b = i + V_p / R_p
    i_b = current + v / p[i, I_RP]
    # R_cp at the step's mid-point charge: q_b is exactly linear over the step, so this makes
    # the frozen-coefficient step second-order accurate near the knee at no extra cost
    r_cp = _r_cp(p, i, _soc(p, i, x[r, S_QB] - 0.5 * i_b * h))
    tau_cp = r_cp * p[i, I_CCP]
    decay_cp = math.exp(-h / tau_cp)
    # exact R–C steps towards their steady charges i_b * tau
    x[r, S_QS] = i_b * tau_s + (x[r, S_QS] - i_b * tau_s) * decay_s
    x[r, S_QCP] = i_b * tau_cp + (x[r, S_QCP] - i_b * tau_cp) * decay_cp
    x[r, S_QB] -= i_b * h
    # eq. 7 with the pack's resistance from the circuit: exact step towards T_inf
    heat = (p[i, I_RS] + r_cp) * current * current
    t_inf = ambient + heat / p[i, I_H]
    x[r, S_T] = t_inf + (x[r, S_T] - t_inf) * decay_t


@njit(**_JIT)
def _pack_advance(p, x, current, ambient, dt, max_dt):
    """Advance one pack state ``x`` (in place; parameters ``p``, both one row) by ``dt`` seconds
    at constant terminal current."""
    if dt <= 0.0:
        return
    p2 = p.reshape((1, p.shape[0]))
    x2 = x.reshape((1, x.shape[0]))
    n_sub, h = _substeps(dt, max_dt)
    tau_s = p[I_RS] * p[I_CS]
    decay_s, decay_t = _fixed_decays(p2, 0, h, tau_s)
    for _ in range(n_sub):
        _pack_step(p2, 0, x2, 0, current, ambient, h, tau_s, decay_s, decay_t, _terminal_voltage(p2, 0, x2, 0))


@njit(inline="always", **_JIT)
def _motor_heat(m, q, current):
    # core loss scales in with the motor's load until it spins at its no-load current
    load = min(1.0, abs(current) / m[q, M_I0]) if m[q, M_I0] > 0.0 else 1.0
    return m[q, M_RW] * current * current + m[q, M_PIRON] * load


@njit(inline="always", **_JIT)
def _motor_decay(m, q, dt):
    return math.exp(-dt * m[q, M_H] / m[q, M_CT])


@njit(inline="always", **_JIT)
def _thermal_step(m, q, temperature, current, ambient, decay):
    """Motor ``m[q]``'s temperature after a step whose decay factor is ``decay`` (``_motor_decay``)."""
    t_inf = ambient + _motor_heat(m, q, current) / m[q, M_H]
    return t_inf + (temperature - t_inf) * decay


@njit(inline="always", **_JIT)
def _thermal_advance(m, temperature, current, ambient, dt):
    """One motor (parameters ``m``, one row) over ``dt`` seconds."""
    if dt <= 0.0:
        return temperature
    m2 = m.reshape((1, m.shape[0]))
    return _thermal_step(m2, 0, temperature, current, ambient, _motor_decay(m2, 0, dt))


# A driver that steps the same pack (or motor) over and over keeps, per pack, its last interval
# and what depends on that interval only, in a row of a small table ("step cache"), so a profile
# of equal steps computes those exponentials once instead of at every step.
(C_DT, C_NSUB, C_H, C_TAU_S, C_DECAY_S, C_DECAY_T) = range(6)
N_STEP_CACHE = 6


@njit(inline="always", **_JIT)
def _reset_step_cache(p, i, cache, r):
    """Row ``r`` of a step cache for pack parameters ``p[i]``: no interval seen yet."""
    cache[r, C_DT] = -1.0  # dt is never negative
    cache[r, C_TAU_S] = p[i, I_RS] * p[i, I_CS]


@njit(inline="always", **_JIT)
def _pack_advance_cached(p, i, x, r, current, ambient, dt, max_dt, v, cache):
    """``_pack_advance`` of state row ``x[r]`` (parameters ``p[i]``) for a driver that knows the
    terminal voltage ``v`` at the start and keeps the pack's step cache in ``cache[r]``
    (``_reset_step_cache``): the same operations, so the same numbers. Returns the terminal
    voltage at the end."""
    if dt <= 0.0:
        return v
    if dt != cache[r, C_DT]:
        n_sub, h = _substeps(dt, max_dt)
        cache[r, C_NSUB] = n_sub
        cache[r, C_H] = h
        cache[r, C_DECAY_S], cache[r, C_DECAY_T] = _fixed_decays(p, i, h, cache[r, C_TAU_S])
        cache[r, C_DT] = dt
    h = cache[r, C_H]
    tau_s = cache[r, C_TAU_S]
    decay_s = cache[r, C_DECAY_S]
    decay_t = cache[r, C_DECAY_T]
    _pack_step(p, i, x, r, current, ambient, h, tau_s, decay_s, decay_t, v)
    for _ in range(1, int(cache[r, C_NSUB])):
        _pack_step(p, i, x, r, current, ambient, h, tau_s, decay_s, decay_t, _terminal_voltage(p, i, x, r))
    return _terminal_voltage(p, i, x, r)


@njit(inline="always", **_JIT)
def _pack_step_soa(p, p0, x, x0, cache, c0, b, lo, hi, current, ambient, v, work):
    """``_pack_advance_cached`` of lanes ``lo`` … ``hi`` - 1 of one pack at once, each taking one step
    (``dt`` > 0 and one sub-step, its step cache already set for the interval), in tables with the
    lane innermost: parameter ``I_*`` of lane l is ``p[p0 + I_*, l]``, state ``x[x0 + S_*, l]``,
    step cache ``cache[c0 + C_*, l]``; terminal current ``current[b, l]``, voltage ``v[b, l]``
    (read at the start, written at the end), ambient ``ambient[l]``. ``_pack_step``'s operations per
    lane in its order (the same numbers, bit for bit), stage by stage over the lanes: the
    arithmetic stages compile to SIMD instructions and the exponentials of the lanes overlap.
    ``work`` is (3, LANES)."""
    for l in range(lo, hi):
        work[0, l] = current[b, l] + v[b, l] / p[p0 + I_RP, l]  # i_b
        q_mid = x[x0 + S_QB, l] - 0.5 * work[0, l] * cache[c0 + C_H, l]
        work[1, l] = p[p0 + I_RCP2, l] * (1.0 - (1.0 - (p[p0 + I_QMAX, l] - q_mid) / p[p0 + I_CMAX, l]))
    for l in range(lo, hi):
        work[1, l] = math.exp(work[1, l])
    for l in range(lo, hi):
        work[1, l] = p[p0 + I_RCP0, l] + p[p0 + I_RCP1, l] * work[1, l]  # r_cp
        work[2, l] = -cache[c0 + C_H, l] / (work[1, l] * p[p0 + I_CCP, l])
    for l in range(lo, hi):
        work[2, l] = math.exp(work[2, l])
    for l in range(lo, hi):
        ib = work[0, l]
        tau_s = cache[c0 + C_TAU_S, l]
        r_cp = work[1, l]
        tau_cp = r_cp * p[p0 + I_CCP, l]
        x[x0 + S_QS, l] = ib * tau_s + (x[x0 + S_QS, l] - ib * tau_s) * cache[c0 + C_DECAY_S, l]
        x[x0 + S_QCP, l] = ib * tau_cp + (x[x0 + S_QCP, l] - ib * tau_cp) * work[2, l]
        x[x0 + S_QB, l] -= ib * cache[c0 + C_H, l]
        heat = (p[p0 + I_RS, l] + r_cp) * current[b, l] * current[b, l]
        t_inf = ambient[l] + heat / p[p0 + I_H, l]
        x[x0 + S_T, l] = t_inf + (x[x0 + S_T, l] - t_inf) * cache[c0 + C_DECAY_T, l]
        v[b, l] = (x[x0 + S_QB, l] / p[p0 + I_CB, l] - x[x0 + S_QCP, l] / p[p0 + I_CCP, l]
                   - x[x0 + S_QS, l] / p[p0 + I_CS, l])


#: vectors a driver advances together, time loop outside (see ``_simulate_pack_block``)
LANES = 16


@njit(inline="always", **_JIT)
def _simulate_pack_block(j0, params, x0, dt, current, ambient, max_dt, voltage, temperature, soc, states,
                         record_states, final):
    """Vectors j0 … j0 + LANES - 1 (those that exist) over the whole profile, one sample at a time.

    One vector's step is a chain of dependent divisions and exponentials. Here the block's
    vectors take each step together, stage by stage over lanes: each stage's lanes are independent,
    so the arithmetic ones compile to SIMD instructions and the two exponentials of the lanes
    overlap in the processor instead of waiting on each other. Per vector the operations are
    ``_pack_step``'s, in its order, on the same values (the same numbers, bit for bit): the terminal
    voltage is carried from the previous output, and the decay factors that depend on the interval
    only are recomputed when the interval changes. A step where some lane does not simply advance
    once (no time passes, or the interval is cut into sub-steps) goes lane by lane through
    ``_pack_step`` as ``_pack_advance`` would."""
    n = current.shape[1]
    nl = min(LANES, params.shape[0] - j0)
    pt = np.empty((N_PACK_PARAMS, LANES))  # parameters, one lane vector per parameter
    xs = np.empty((N_PACK_STATE, LANES))   # states likewise
    for lane in range(nl):
        for i in range(N_PACK_PARAMS):
            pt[i, lane] = params[j0 + lane, i]
        for s in range(N_PACK_STATE):
            xs[s, lane] = x0[j0 + lane, s]
    v = np.empty(LANES)
    tau_s = np.empty(LANES)
    for lane in range(nl):
        v[lane] = xs[S_QB, lane] / pt[I_CB, lane] - xs[S_QCP, lane] / pt[I_CCP, lane] - xs[S_QS, lane] / pt[I_CS, lane]
        tau_s[lane] = pt[I_RS, lane] * pt[I_CS, lane]
    last_dt = np.full(LANES, -1.0)  # dt is never negative: the first interval sets the factors
    n_sub = np.ones(LANES, dtype=np.int64)
    h = np.empty(LANES)
    decay_s = np.empty(LANES)
    decay_t = np.empty(LANES)
    cur = np.empty(LANES)
    amb = np.empty(LANES)
    i_b = np.empty(LANES)
    r_cp = np.empty(LANES)
    e = np.empty(LANES)
    xl = np.empty((1, N_PACK_STATE))
    shared_cur = current.shape[0] == 1
    shared_amb = ambient.shape[0] == 1
    shared_dt = dt.shape[0] == 1
    for k in range(n):
        n_moving = 0
        n_single = 0
        for lane in range(nl):
            d = dt[0 if shared_dt else j0 + lane, k]
            cur[lane] = current[0 if shared_cur else j0 + lane, k]
            amb[lane] = ambient[0 if shared_amb else j0 + lane, k]
            if not d <= 0.0:  # as _pack_advance: a NaN interval steps (to NaN)
                n_moving += 1
                if d != last_dt[lane]:
                    n_sub[lane], h[lane] = _substeps(d, max_dt)
                    decay_s[lane], decay_t[lane] = _fixed_decays(params, j0 + lane, h[lane], tau_s[lane])
                    last_dt[lane] = d
                if n_sub[lane] == 1:
                    n_single += 1
        if n_single == nl:
            # every lane one step: _pack_step over the lanes, stage by stage
            for lane in range(nl):
                i_b[lane] = cur[lane] + v[lane] / pt[I_RP, lane]
                soc_mid = 1.0 - (pt[I_QMAX, lane] - (xs[S_QB, lane] - 0.5 * i_b[lane] * h[lane])) / pt[I_CMAX, lane]
                e[lane] = pt[I_RCP2, lane] * (1.0 - soc_mid)
            for lane in range(nl):
                e[lane] = math.exp(e[lane])
            for lane in range(nl):
                r_cp[lane] = pt[I_RCP0, lane] + pt[I_RCP1, lane] * e[lane]
                e[lane] = -h[lane] / (r_cp[lane] * pt[I_CCP, lane])
            for lane in range(nl):
                e[lane] = math.exp(e[lane])
            for lane in range(nl):
                ib = i_b[lane]
                tau_cp = r_cp[lane] * pt[I_CCP, lane]
                xs[S_QS, lane] = ib * tau_s[lane] + (xs[S_QS, lane] - ib * tau_s[lane]) * decay_s[lane]
                xs[S_QCP, lane] = ib * tau_cp + (xs[S_QCP, lane] - ib * tau_cp) * e[lane]
                xs[S_QB, lane] -= ib * h[lane]
                heat = (pt[I_RS, lane] + r_cp[lane]) * cur[lane] * cur[lane]
                t_inf = amb[lane] + heat / pt[I_H, lane]
                xs[S_T, lane] = t_inf + (xs[S_T, lane] - t_inf) * decay_t[lane]
                v[lane] = (xs[S_QB, lane] / pt[I_CB, lane] - xs[S_QCP, lane] / pt[I_CCP, lane]
                           - xs[S_QS, lane] / pt[I_CS, lane])
        elif n_moving > 0:
            for lane in range(nl):
                if dt[0 if shared_dt else j0 + lane, k] <= 0.0:
                    continue
                j = j0 + lane
                for s in range(N_PACK_STATE):
                    xl[0, s] = xs[s, lane]
                _pack_step(params, j, xl, 0, cur[lane], amb[lane], h[lane], tau_s[lane], decay_s[lane], decay_t[lane],
                           v[lane])
                for _ in range(1, n_sub[lane]):
                    _pack_step(params, j, xl, 0, cur[lane], amb[lane], h[lane], tau_s[lane], decay_s[lane],
                               decay_t[lane], _terminal_voltage(params, j, xl, 0))
                for s in range(N_PACK_STATE):
                    xs[s, lane] = xl[0, s]
                v[lane] = _terminal_voltage(params, j, xl, 0)
        for lane in range(nl):
            j = j0 + lane
            voltage[j, k] = v[lane]
            temperature[j, k] = xs[S_T, lane]
            soc[j, k] = 1.0 - (pt[I_QMAX, lane] - xs[S_QB, lane]) / pt[I_CMAX, lane]
            if record_states:
                for s in range(N_PACK_STATE):
                    states[j, k, s] = xs[s, lane]
    for lane in range(nl):
        for s in range(N_PACK_STATE):
            final[j0 + lane, s] = xs[s, lane]


@njit(**_JIT)
def _simulate_packs(params, x0, dt, current, ambient, max_dt, voltage, temperature, soc, states,
                    record_states, final):
    for j0 in range(0, params.shape[0], LANES):
        _simulate_pack_block(j0, params, x0, dt, current, ambient, max_dt, voltage, temperature, soc, states,
                             record_states, final)


@njit(parallel=True, **_JIT)
def _simulate_packs_parallel(params, x0, dt, current, ambient, max_dt, voltage, temperature, soc, states,
                             record_states, final):
    # the same blocks spread over the cores; only for callers on one thread (numba's default
    # threading layer does not take parallel launches from several Python threads at once)
    for block in prange((params.shape[0] + LANES - 1) // LANES):
        _simulate_pack_block(np.int64(block) * LANES, params, x0, dt, current, ambient, max_dt, voltage,
                             temperature, soc, states, record_states, final)


@njit(**_JIT)
def _simulate_motor_thermal(params, temp0, dt, current, ambient, out):
    n_vec = out.shape[0]
    n = current.shape[1]
    for j in range(n_vec):
        q = j if params.shape[0] > 1 else 0
        ci = j if current.shape[0] > 1 else 0
        ai = j if ambient.shape[0] > 1 else 0
        di = j if dt.shape[0] > 1 else 0
        temp = temp0[j]
        last_dt = -1.0  # dt is never negative: the first interval sets the decay
        decay = 0.0
        for k in range(n):
            h = dt[di, k]
            if not h <= 0.0:  # as _thermal_advance
                if h != last_dt:
                    decay = _motor_decay(params, q, h)
                    last_dt = h
                temp = _thermal_step(params, q, temp, current[ci, k], ambient[ai, k], decay)
            out[j, k] = temp


def _rows(a: np.ndarray | float, n_vec: int, n: int, name: str) -> np.ndarray:
    """Shape an input as (1, n) (shared) or (n_vec, n) (per vector), float64, C-contiguous."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((1, n), float(arr))
    elif arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n or arr.shape[0] not in (1, n_vec):
        raise ValueError(f"{name}: expected shape ({n},) or ({n_vec}, {n}), got {np.shape(a)}")
    return owned(arr)


def owned(a, dtype=np.float64) -> np.ndarray:
    """``a`` as a writable C-contiguous array of ``dtype``, copied only when it is not one already.
    Every array a compiled entry point gets goes through here: numba compiles one machine-code
    version per argument type, and a read-only array (a ``broadcast_to`` view, which
    ``ascontiguousarray`` hands back as it is when its shape already fits) is another type. The
    vehicle driver then compiled a second time, minutes of CPU, wherever a caller happened to pass
    one (a planner's first airspeed optimisation, a calibrated pack's route risk)."""
    a = np.asarray(a, dtype=dtype)
    return a if a.flags.c_contiguous and a.flags.writeable else np.array(a, dtype=dtype, order="C")


def _params2d(params: np.ndarray, width: int, name: str) -> np.ndarray:
    arr = owned(np.atleast_2d(np.asarray(params, dtype=np.float64)))
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"{name}: expected shape (N, {width}), got {np.shape(params)}")
    return arr


@dataclass(frozen=True)
class PackTrajectory:
    voltage: np.ndarray      # (N, n) terminal voltage, V
    temperature: np.ndarray  # (N, n) pack temperature, °C
    soc: np.ndarray          # (N, n) state of charge, 1
    final_state: np.ndarray  # (N, 4) PACK_STATE after the last sample (extended: (N, 5) EXT_PACK_STATE)
    states: np.ndarray | None = None  # (N, n, 4) if requested (extended: (N, n, 5))


def _pack_inputs(params, n_params: int, x0, n_state: int, dt, current, ambient):
    """Both variants' inputs as contiguous (N, ·) rows: params, x0, dt, current, ambient."""
    params = _params2d(params, n_params, "params")
    n_vec = params.shape[0]
    x0 = owned(np.broadcast_to(np.asarray(x0, dtype=np.float64), (n_vec, n_state)))
    cur = np.asarray(current, dtype=np.float64)
    n = cur.shape[-1]
    cur = _rows(cur, n_vec, n, "current")
    dt_ = _rows(dt, n_vec, n, "dt")
    amb = _rows(ambient, n_vec, n, "ambient")
    if np.any(dt_ < 0):
        raise ValueError("dt: time steps must be non-negative (sort and de-duplicate timestamps first)")
    return params, x0, dt_, cur, amb


def simulate_packs(params: np.ndarray, x0: np.ndarray, dt: np.ndarray, current: np.ndarray,
                   ambient: np.ndarray | float, *, max_dt: float = DEFAULT_MAX_DT,
                   record_states: bool = False, variant: str = "paper",
                   measured_temperature: np.ndarray | None = None, parallel: bool = False) -> PackTrajectory:
    """Simulate N packs (one parameter vector each) over a current/ambient profile.

    ``variant`` "paper": params (N, 12) in PACK_PARAMS order, x0 (N, 4) in PACK_STATE order;
    "extended": params (N, N_EXT_PARAMS) in EXT_PACK_PARAMS order, x0 (N, 5) in EXT_PACK_STATE order, and
    optionally ``measured_temperature`` ((n,) or (N, n), NaN where missing) to drive the resistances'
    temperature dependence instead of the model's own temperature (the electrical fit uses it).
    dt, current, ambient (n,) shared or (N, n) per vector — see the module docstring for the time
    convention. ``parallel`` spreads the vectors over the cores (call it from one thread only).
    """
    if variant == "extended":
        return _simulate_packs_extended(params, x0, dt, current, ambient, max_dt, record_states,
                                        measured_temperature, parallel)
    if variant != "paper":
        raise ValueError(f"variant: expected one of {MODEL_VARIANTS}, got {variant!r}")
    params, x0, dt_, cur, amb = _pack_inputs(params, N_PACK_PARAMS, x0, N_PACK_STATE, dt, current, ambient)
    n_vec, n = params.shape[0], cur.shape[1]
    voltage = np.empty((n_vec, n))
    temperature = np.empty((n_vec, n))
    soc = np.empty((n_vec, n))
    states = np.empty((n_vec, n, N_PACK_STATE) if record_states else (1, 1, N_PACK_STATE))
    final = np.empty((n_vec, N_PACK_STATE))
    run = _simulate_packs_parallel if parallel else _simulate_packs
    run(params, x0, dt_, cur, amb, float(max_dt), voltage, temperature, soc, states, record_states, final)
    return PackTrajectory(voltage, temperature, soc, final, states if record_states else None)


def simulate_motor_thermal(params: np.ndarray, temp0: np.ndarray | float, dt: np.ndarray,
                           current: np.ndarray, ambient: np.ndarray | float) -> np.ndarray:
    """Motor temperature (N, n), °C, from per-motor current; params (N or 1, 5) in MOTOR_PARAMS order."""
    params = _params2d(params, N_MOTOR_PARAMS, "params")
    cur = np.asarray(current, dtype=np.float64)
    n = cur.shape[-1]
    n_vec = max(params.shape[0], cur.shape[0] if cur.ndim == 2 else 1, np.size(temp0))
    t0 = owned(np.broadcast_to(np.asarray(temp0, dtype=np.float64), (n_vec,)))
    out = np.empty((n_vec, n))
    _simulate_motor_thermal(params, t0, _rows(dt, n_vec, n, "dt"), _rows(cur, n_vec, n, "current"),
                            _rows(ambient, n_vec, n, "ambient"), out)
    return out


def initial_pack_state(params: np.ndarray, soc: np.ndarray | float, temperature: np.ndarray | float,
                       current: np.ndarray | float = 0.0) -> np.ndarray:
    """Pack states (N, 4) at a given SoC and temperature with both R–C pairs settled at ``current``."""
    params = _params2d(params, N_PACK_PARAMS, "params")
    soc = np.asarray(soc, dtype=np.float64)
    q_b = params[:, I_QMAX] - (1.0 - soc) * params[:, I_CMAX]
    r_cp = concentration_resistance(params, soc)
    current = np.asarray(current, dtype=np.float64)
    x = np.empty((params.shape[0], N_PACK_STATE))
    x[:, S_QB] = q_b
    x[:, S_QCP] = current * r_cp * params[:, I_CCP]
    x[:, S_QS] = current * params[:, I_RS] * params[:, I_CS]
    x[:, S_T] = temperature
    return x


def terminal_voltage(params: np.ndarray, states: np.ndarray) -> np.ndarray:
    """V = V_b - V_cp - V_s (eq. 4 with the R_s–C_s pair) for states (..., 4)."""
    params = np.asarray(params, dtype=np.float64)
    states = np.asarray(states, dtype=np.float64)
    return (states[..., S_QB] / params[..., I_CB] - states[..., S_QCP] / params[..., I_CCP]
            - states[..., S_QS] / params[..., I_CS])


def state_of_charge(params: np.ndarray, states: np.ndarray) -> np.ndarray:
    params = np.asarray(params, dtype=np.float64)
    return 1.0 - (params[..., I_QMAX] - np.asarray(states)[..., S_QB]) / params[..., I_CMAX]


def concentration_resistance(params: np.ndarray, soc: np.ndarray | float) -> np.ndarray:
    """R_cp(SoC) = R_cp0 + R_cp1 exp(R_cp2 (1 - SoC)) (eq. 6), vectorised over packs."""
    params = np.asarray(params, dtype=np.float64)
    return params[..., I_RCP0] + params[..., I_RCP1] * np.exp(params[..., I_RCP2] * (1.0 - np.asarray(soc)))


def soc_at_bulk_voltage(params: np.ndarray, bulk_voltage: np.ndarray | float) -> np.ndarray:
    """The SoC whose bulk charge q_b = C_b V_b gives ``bulk_voltage`` (unclipped)."""
    params = np.asarray(params, dtype=np.float64)
    return 1.0 - (params[..., I_QMAX] - params[..., I_CB] * np.asarray(bulk_voltage)) / params[..., I_CMAX]


def pack_states_at_soc(params: np.ndarray, soc: np.ndarray) -> np.ndarray:
    """q_b for a SoC; handy for estimators that keep SoC as their state."""
    params = np.asarray(params, dtype=np.float64)
    return params[..., I_QMAX] - (1.0 - np.asarray(soc)) * params[..., I_CMAX]


# ---- the extended equivalent circuit (variant "extended") ----------------------------------------
#
# docs/model.md gives the equations. States: SoC, the two R–C voltages, the temperature and the
# surface depletion. The open-circuit voltage is a monotone piecewise-cubic (PCHIP, Fritsch–Carlson
# slopes) through knots at EXT_OCV_SOC, parametrised by the voltage at SoC 0 and positive increments,
# so any parameter vector inside the bounds is monotone. Every resistance is scaled by
#     f(T, s) = exp(E_r (1/T_K - 1/298.15 K)) * (1 + k_soc exp(-s / soc_knee)),   s = SoC - s_d,
# the charge-transfer (Butler–Volmer) overpotential b_ct (T_K/298.15) asinh(I g / i_ct), with g like f
# but its own activation temperature E_ct, is linear at small current and logarithmic at high
# current; heat is I (OCV(s) - V) - I T_K dU/dT (irreversible plus entropic), and the pack exchanges
# heat with the air as in eq. 7. With f, g and the OCV slope frozen over a step, the R–C pairs, the
# depletion and the temperature have exact exponential steps, as in the paper variant.
#
# Solid diffusion: the OCV is read at the particles' *surface* SoC s, where the depletion s_d relaxes
# towards I k_d / C_max with its own time constant tau_d (a one-state diffusion approximation). On the
# plateau it acts as one more R–C drop; near empty, where the OCV falls steeply, it makes the knee
# arrive earlier and steeper at high current, as it does in real cells.

#: SoC of the open-circuit-voltage knots: denser at the bottom, where the curve bends, every 0.05 above
#: 0.2 and every 0.025 above 0.7, where flights start. Every flight starts from a rest voltage read
#: through this curve, so a feature it cannot draw (a graphite staging step) is an initial-SoC error,
#: and on a flight to the cut-off 0.005 of SoC is 25-50 mV of RMSE (docs/model.md)
EXT_OCV_SOC = np.round(np.concatenate([[0.0, 0.03, 0.07, 0.12], np.arange(0.2, 0.7 - 1e-9, 0.05),
                                       np.arange(0.7, 1.0 + 1e-9, 0.025)]), 3)
N_OCV_KNOTS = len(EXT_OCV_SOC)
#: every knot sits on a 0.005 grid of SoC, so a grid cell's index (one multiply) names the knot
#: interval that holds it; ``_ocv_eval_at`` looks the interval up there instead of bisecting
#: (a chain of five unpredictable branches per evaluation)
_OCV_CELLS_PER_SOC = 200.0
_OCV_INTERVAL_OF_CELL = np.clip(np.searchsorted(EXT_OCV_SOC, np.arange(int(_OCV_CELLS_PER_SOC)) / _OCV_CELLS_PER_SOC,
                                                side="right") - 1, 0, N_OCV_KNOTS - 2).astype(np.int64)
EXT_T_REF_K = 298.15
EXT_PACK_PARAMS: tuple[str, ...] = (
    "R_0", "R_1", "tau_1", "R_2", "tau_2", "E_r", "E_ct", "k_soc", "soc_knee", "b_ct", "i_ct", "k_d", "tau_d", "C_max", "C_t", "h",
    "dU_dT",
    "ocv_0",
) + tuple(f"docv_{k}" for k in range(1, N_OCV_KNOTS))
EXT_PACK_STATE: tuple[str, ...] = ("soc", "v_1", "v_2", "T", "s_d")
N_EXT_STATE = len(EXT_PACK_STATE)
N_EXT_PARAMS = len(EXT_PACK_PARAMS)
(E_R0, E_R1, E_TAU1, E_R2, E_TAU2, E_ER, E_ECT, E_KSOC, E_KNEE, E_BCT, E_ICT, E_KD, E_TAUD, E_CMAX, E_CT,
 E_H, E_DUDT, E_OCV0) = range(18)
(X_SOC, X_V1, X_V2, X_T, X_SD) = range(N_EXT_STATE)


@njit(inline="always", **_JIT)
def _pchip_slope(h0, h1, d0, d1):
    # Fritsch–Carlson interior slope: weighted harmonic mean of the neighbouring secants (0 at an extremum)
    if d0 * d1 <= 0.0:
        return 0.0
    w1 = 2.0 * h1 + h0
    w2 = h1 + 2.0 * h0
    return (w1 + w2) / (w1 / d0 + w2 / d1)


@njit(**_JIT)
def _ocv_knots(p, y, d):
    """Knot voltages ``y`` and PCHIP slopes ``d`` of one extended vector (once per simulation)."""
    xs = EXT_OCV_SOC
    last = N_OCV_KNOTS - 1
    y[0] = p[E_OCV0]
    for m in range(1, N_OCV_KNOTS):
        y[m] = y[m - 1] + p[E_OCV0 + m]
    d[0] = (y[1] - y[0]) / (xs[1] - xs[0])
    d[last] = (y[last] - y[last - 1]) / (xs[last] - xs[last - 1])
    for m in range(1, last):
        h0 = xs[m] - xs[m - 1]
        h1 = xs[m + 1] - xs[m]
        d[m] = _pchip_slope(h0, h1, (y[m] - y[m - 1]) / h0, (y[m + 1] - y[m]) / h1)


@njit(inline="always", **_JIT)
def _ocv_eval(y, d, soc):
    """Open-circuit voltage (V, pack) at ``soc`` from knots; linear beyond the end knots."""
    return _ocv_eval_at(y.reshape((1, y.shape[0])), d.reshape((1, d.shape[0])), 0, soc)


@njit(inline="always", **_JIT)
def _ocv_eval_at(y, d, i, soc):
    """``_ocv_eval`` of row ``i`` of knot tables ``y`` and ``d`` (indexed, not viewed: see ``_ext_substeps_at``)."""
    xs = EXT_OCV_SOC
    last = N_OCV_KNOTS - 1
    if not soc > xs[0]:  # NaN too (NaN out), before the grid lookup below
        return y[i, 0] + (soc - xs[0]) * d[i, 0]
    if soc >= xs[last]:
        return y[i, last] + (soc - xs[last]) * d[i, last]
    k = _ocv_interval(soc)
    return _hermite(soc, xs[k], xs[k + 1] - xs[k], y[i, k], d[i, k], y[i, k + 1], d[i, k + 1])


@njit(inline="always", **_JIT)
def _ocv_interval(soc):
    """The knot interval k holding ``soc`` (xs[k] < soc <= xs[k + 1], as a bisection finds it), for
    xs[0] < soc < xs[-1]: the grid cell's interval, moved by at most one knot where rounding puts
    soc across a knot."""
    xs = EXT_OCV_SOC
    k = _OCV_INTERVAL_OF_CELL[min(int(soc * _OCV_CELLS_PER_SOC), _OCV_INTERVAL_OF_CELL.shape[0] - 1)]
    while k > 0 and soc <= xs[k]:
        k -= 1
    while soc > xs[k + 1]:
        k += 1
    return k


@njit(inline="always", **_JIT)
def _hermite(soc, x_k, h_k, y_k, d_k, y_k1, d_k1):
    """The cubic Hermite piece from knot (x_k, y_k, slope d_k) to (x_k + h_k, y_k1, d_k1) at ``soc``."""
    t = (soc - x_k) / h_k
    t2 = t * t
    t3 = t2 * t
    return ((2.0 * t3 - 3.0 * t2 + 1.0) * y_k + (t3 - 2.0 * t2 + t) * h_k * d_k
            + (-2.0 * t3 + 3.0 * t2) * y_k1 + (t3 - t2) * h_k * d_k1)


@njit(inline="always", **_JIT)
def _low_charge(p, soc):
    """Rise of the resistances and of the exchange current's inverse as the (surface) SoC empties."""
    return _low_charge_of(p[E_KSOC], p[E_KNEE], soc)


@njit(inline="always", **_JIT)
def _low_charge_of(k_soc, knee, soc):
    return 1.0 + k_soc * math.exp(-max(soc, 0.0) / knee)


@njit(inline="always", **_JIT)
def _resistance_factor(p, temperature_c, soc):
    arrhenius = math.exp(p[E_ER] * (1.0 / (temperature_c + 273.15) - 1.0 / EXT_T_REF_K))
    return arrhenius * _low_charge(p, soc)


@njit(inline="always", **_JIT)
def _kinetic_rho(p, current, temperature_c, rho):
    return _kinetic_of(p[E_ECT], p[E_BCT], p[E_ICT], current, temperature_c, rho)


@njit(inline="always", **_JIT)
def _kinetic_of(e_ct, b_ct, i_ct, current, temperature_c, rho):
    """Butler–Volmer overpotential b_ct (T/T_ref) asinh(I g / i_ct): the slope is the thermal voltage
    (∝ T), and the exchange current has its own activation temperature E_ct (charge transfer is
    activated differently from the electrolyte's and contacts' resistance) and falls as the surface
    empties (``rho``, the same low-charge factor as the resistances)."""
    t_k = temperature_c + 273.15
    g = math.exp(e_ct * (1.0 / t_k - 1.0 / EXT_T_REF_K)) * rho
    return b_ct * (t_k / EXT_T_REF_K) * math.asinh(current * g / i_ct)


@njit(inline="always", **_JIT)
def _kinetic(p, current, temperature_c, soc):
    return _kinetic_rho(p, current, temperature_c, _low_charge(p, soc))


@njit(**_JIT)
def _ext_advance(p, y, d, x, current, ambient, t_drive, dt, max_dt):
    """Advance one extended pack state ``x`` (in place) by ``dt`` s at constant current.

    ``t_drive`` (°C) sets the resistances' temperature if finite (a measured temperature), else the
    model's own temperature does. Returns the terminal voltage at the end of the step."""
    if dt <= 0.0:
        t_res = x[X_T] if math.isnan(t_drive) else t_drive
        f = _resistance_factor(p, t_res, x[X_SOC] - x[X_SD])
        return (_ocv_eval(y, d, x[X_SOC] - x[X_SD]) - current * p[E_R0] * f
                - _kinetic(p, current, t_res, x[X_SOC] - x[X_SD])
                - x[X_V1] - x[X_V2])
    n_sub, h, decay_1, decay_2, decay_d, decay_t = _ext_decays(p, dt, max_dt)
    return _ext_substeps(p, y, d, x, current, ambient, t_drive, n_sub, h, decay_1, decay_2, decay_d, decay_t)


@njit(inline="always", **_JIT)
def _ext_decays(p, dt, max_dt):
    """Sub-steps of an interval and the exact decay factors of one sub-step (they depend on dt only,
    so a log at a steady rate computes them once)."""
    n_sub = 1
    if dt > max_dt:
        # bounded like the paper variant's step: work follows samples, not the span of a log gap
        n_sub = min(int(math.ceil(dt / max_dt)), MAX_SUBSTEPS)
    h = dt / n_sub
    return (n_sub, h, math.exp(-h / p[E_TAU1]), math.exp(-h / p[E_TAU2]), math.exp(-h / p[E_TAUD]),
            math.exp(-h * p[E_H] / p[E_CT]))


@njit(inline="always", **_JIT)
def _ext_substeps(p, y, d, x, current, ambient, t_drive, n_sub, h, decay_1, decay_2, decay_d, decay_t):
    return _ext_substeps_at(p.reshape((1, p.shape[0])), 0, y.reshape((1, y.shape[0])), d.reshape((1, d.shape[0])), 0,
                            x.reshape((1, x.shape[0])), 0, current, ambient, t_drive, n_sub, h, decay_1, decay_2,
                            decay_d, decay_t)


@njit(inline="always", **_JIT)
def _ext_substeps_at(p, i, y, d, m, x, r, current, ambient, t_drive, n_sub, h, decay_1, decay_2, decay_d, decay_t):
    """The extended step of state row ``x[r]`` (parameters ``p[i]``, OCV knots ``y[m]`` and ``d[m]``),
    in place; returns the terminal voltage at its end. Tables indexed by row, not viewed: in numba
    each row view costs two atomic reference counts, which in a driver's inner loop cost more than
    the step's arithmetic."""
    d_soc = current * h / p[i, E_CMAX]
    s_inf = current * p[i, E_KD] / p[i, E_CMAX]
    v = 0.0
    for _ in range(n_sub):
        t_res = x[r, X_T] if math.isnan(t_drive) else t_drive
        s_d = s_inf + (x[r, X_SD] - s_inf) * decay_d
        # the low-charge rise follows the particles' surface SoC (the exchange current falls as the
        # surface empties), so at high current it arrives early and steep, as the knee does
        surface_mid = x[r, X_SOC] - 0.5 * d_soc - 0.5 * (x[r, X_SD] + s_d)
        rho = _low_charge_of(p[i, E_KSOC], p[i, E_KNEE], surface_mid)
        f = math.exp(p[i, E_ER] * (1.0 / (t_res + 273.15) - 1.0 / EXT_T_REF_K)) * rho
        i1 = current * p[i, E_R1] * f
        i2 = current * p[i, E_R2] * f
        v1 = i1 + (x[r, X_V1] - i1) * decay_1
        v2 = i2 + (x[r, X_V2] - i2) * decay_2
        # heat over the step: I (OCV(surface) - V) at the step's mean overpotential, minus the entropic
        # term. The surface-depletion drop OCV(SoC) - OCV(SoC - s_d) is not heat: its energy sits in the
        # particles' concentration gradient (the heat of mixing, released slowly as it relaxes and
        # neglected, as in the usual cell energy balance). Counting it as heat over-heated the packs
        # by kelvins in the last minutes before the cut-off, where the OCV is steep.
        eta = current * p[i, E_R0] * f + _kinetic_of(p[i, E_ECT], p[i, E_BCT], p[i, E_ICT], current, t_res, rho)
        soc_new = x[r, X_SOC] - d_soc
        ocv_surface = _ocv_eval_at(y, d, m, soc_new - s_d)
        over = eta + 0.5 * (x[r, X_V1] + v1 + x[r, X_V2] + v2)
        heat = current * over - current * (x[r, X_T] + 273.15) * p[i, E_DUDT]
        t_inf = ambient + heat / p[i, E_H]
        x[r, X_T] = t_inf + (x[r, X_T] - t_inf) * decay_t
        x[r, X_V1] = v1
        x[r, X_V2] = v2
        x[r, X_SD] = s_d
        x[r, X_SOC] = soc_new
        v = ocv_surface - eta - v1 - v2
    return v


#: decay-table rows of an extended pack's interval (``_ext_decays``): sub-step length, then the R1, R2,
#: diffusion and thermal decays
(D_H, D_1, D_2, D_D, D_T) = range(5)
N_EXT_DECAYS = 5
#: rows of a lane's cached OCV knot interval (``_cache_ocv_interval``): its ends x_k and x_k+1 and
#: their difference, the knot values and slopes at either end
(O_X, O_X1, O_H, O_Y0, O_D0, O_Y1, O_D1) = range(7)
N_OCV_CACHE = 7


@njit(inline="always", **_JIT)
def _in_cached_interval(oc, o0, l, soc):
    """Whether ``_ocv_eval_at`` would evaluate ``soc`` on lane ``l``'s cached interval (an interior
    one: at the last knot it extrapolates instead)."""
    return (oc[o0 + O_X, l] < soc) & (soc <= oc[o0 + O_X1, l]) & (soc < EXT_OCV_SOC[-1])


@njit(inline="always", **_JIT)
def _cache_ocv_interval(y, d, i, soc, oc, o0, l):
    """Lane ``l`` caches the knot interval of row ``i`` of ``y``/``d`` holding ``soc``; outside
    the knots (or NaN), an empty interval."""
    xs = EXT_OCV_SOC
    if soc > xs[0] and soc < xs[N_OCV_KNOTS - 1]:
        k = _ocv_interval(soc)
        oc[o0 + O_X, l], oc[o0 + O_X1, l], oc[o0 + O_H, l] = xs[k], xs[k + 1], xs[k + 1] - xs[k]
        oc[o0 + O_Y0, l], oc[o0 + O_D0, l], oc[o0 + O_Y1, l], oc[o0 + O_D1, l] = y[i, k], d[i, k], y[i, k + 1], d[i, k + 1]
    else:
        oc[o0 + O_X, l] = np.inf


@njit(inline="always", **_JIT)
def ocv_lanes(y, d, knot_row, b, oc, o0, a, src, dst, lo, hi):
    """``a[dst, l]`` = the OCV of lane ``l`` of pack ``b`` (knot rows ``knot_row[b, l]`` of ``y``/``d``) at
    SoC ``a[src, l]``: ``_ocv_eval_at``'s value bit for bit, from the knot interval the lane last used
    (``oc[o0 + O_*, l]``), so it is a SIMD stage without a look-up; the lanes whose SoC left it (once
    in hundreds of steps) look it up afterwards and cache the new one."""
    n_moved = 0
    for l in range(lo, hi):
        s = a[src, l]
        a[dst, l] = _hermite(s, oc[o0 + O_X, l], oc[o0 + O_H, l], oc[o0 + O_Y0, l], oc[o0 + O_D0, l],
                             oc[o0 + O_Y1, l], oc[o0 + O_D1, l])
        n_moved += not _in_cached_interval(oc, o0, l, s)
    if n_moved:
        for l in range(lo, hi):
            s = a[src, l]
            if not _in_cached_interval(oc, o0, l, s):
                a[dst, l] = _ocv_eval_at(y, d, knot_row[b, l], s)
                _cache_ocv_interval(y, d, knot_row[b, l], s, oc, o0, l)


#: rows of the scratch table ``_ext_step_soa`` (and ``_pack_step_soa``, which uses the first three) takes
N_EXT_WORK = 14


@njit(inline="always", **_JIT)
def _ext_step_soa(p, p0, y, d, knot_row, oc, o0, x, x0, decay, d0, b, lo, hi, current, ambient, v, work):
    """One step (a single sub-step) of lanes ``lo`` … ``hi`` - 1 of one extended pack at once, in
    tables with the lane innermost: parameter ``E_*`` of lane l is ``p[p0 + E_*, l]``, state
    ``x[x0 + X_*, l]``, decays ``decay[d0 + D_*, l]`` (``_ext_decays``), OCV knots rows
    ``knot_row[b, l]`` of ``y``/``d`` and the knot interval last used ``oc[o0 + O_*, l]``
    (``_cache_ocv_interval``); terminal current ``current[b, l]``, ambient ``ambient[l]``;
    the model's own temperature drives it. Writes the terminal voltages to ``v[b, l]``.

    ``_ext_substeps_at``'s operations per lane, in its order, taken stage by stage over the lanes,
    every stage a SIMD loop: the OCV from each lane's cached knot interval (``ocv_lanes``, bit for
    bit), and the three exponentials and the asinh by ``gcs_pdm.models.lane_math`` instead of
    libm's. Those are within one or two units in the last place of libm's, so a lane follows the
    one-pack step to ~1e-13 relative, not bit for bit (docs/notes/2026-11-27-extended-mc-2.md).
    ``work`` is (N_EXT_WORK, LANES) scratch."""
    for l in range(lo, hi):
        cur = current[b, l]
        cmax = p[p0 + E_CMAX, l]
        work[5, l] = cur * decay[d0 + D_H, l] / cmax  # d_soc
        s_inf = cur * p[p0 + E_KD, l] / cmax
        work[4, l] = s_inf + (x[x0 + X_SD, l] - s_inf) * decay[d0 + D_D, l]  # s_d
        surface_mid = x[x0 + X_SOC, l] - 0.5 * work[5, l] - 0.5 * (x[x0 + X_SD, l] + work[4, l])
        work[0, l] = -max(surface_mid, 0.0) / p[p0 + E_KNEE, l]
        work[1, l] = p[p0 + E_ER, l] * (1.0 / (x[x0 + X_T, l] + 273.15) - 1.0 / EXT_T_REF_K)
        work[6, l] = x[x0 + X_T, l] + 273.15  # t_k
        work[2, l] = p[p0 + E_ECT, l] * (1.0 / work[6, l] - 1.0 / EXT_T_REF_K)
    exp_row(work, 0, 9, lo, hi)
    exp_row(work, 1, 10, lo, hi)
    exp_row(work, 2, 11, lo, hi)
    for l in range(lo, hi):
        rho = 1.0 + p[p0 + E_KSOC, l] * work[9, l]
        work[1, l] = work[10, l] * rho  # f
        work[11, l] = current[b, l] * (work[11, l] * rho) / p[p0 + E_ICT, l]
    asinh_row(work, 11, 3, 13, lo, hi)
    for l in range(lo, hi):
        work[7, l] = x[x0 + X_SOC, l] - work[5, l]  # the SoC after the step
        work[12, l] = work[7, l] - work[4, l]  # at the particles' surface
    ocv_lanes(y, d, knot_row, b, oc, o0, work, 12, 8, lo, hi)
    for l in range(lo, hi):
        cur = current[b, l]
        f = work[1, l]
        i1 = cur * p[p0 + E_R1, l] * f
        i2 = cur * p[p0 + E_R2, l] * f
        v1 = i1 + (x[x0 + X_V1, l] - i1) * decay[d0 + D_1, l]
        v2 = i2 + (x[x0 + X_V2, l] - i2) * decay[d0 + D_2, l]
        eta = cur * p[p0 + E_R0, l] * f + p[p0 + E_BCT, l] * (work[6, l] / EXT_T_REF_K) * work[3, l]
        over = eta + 0.5 * (x[x0 + X_V1, l] + v1 + x[x0 + X_V2, l] + v2)
        heat = cur * over - cur * (x[x0 + X_T, l] + 273.15) * p[p0 + E_DUDT, l]
        t_inf = ambient[l] + heat / p[p0 + E_H, l]
        x[x0 + X_T, l] = t_inf + (x[x0 + X_T, l] - t_inf) * decay[d0 + D_T, l]
        x[x0 + X_V1, l] = v1
        x[x0 + X_V2, l] = v2
        x[x0 + X_SD, l] = work[4, l]
        x[x0 + X_SOC, l] = work[7, l]
        v[b, l] = work[8, l] - eta - v1 - v2


@njit(inline="always", **_JIT)
def _simulate_one_ext(j, params, x0, dt, current, ambient, t_meas, max_dt, voltage, temperature, soc, states,
                      record_states, final):
    n = current.shape[1]
    x = np.empty(N_EXT_STATE)
    p = params[j]
    y = np.empty(N_OCV_KNOTS)
    d = np.empty(N_OCV_KNOTS)
    _ocv_knots(p, y, d)
    # the steps' one-row tables (``_ext_substeps_at`` indexes rows instead of taking views)
    p_row, x_row = p.reshape((1, N_EXT_PARAMS)), x.reshape((1, N_EXT_STATE))
    y_row, d_row = y.reshape((1, N_OCV_KNOTS)), d.reshape((1, N_OCV_KNOTS))
    ci = j if current.shape[0] > 1 else 0
    ai = j if ambient.shape[0] > 1 else 0
    di = j if dt.shape[0] > 1 else 0
    ti = j if t_meas.shape[0] > 1 else 0
    for s in range(N_EXT_STATE):
        x[s] = x0[j, s]
    last_dt = -1.0
    n_sub, h, decay_1, decay_2, decay_d, decay_t = 1, 0.0, 1.0, 1.0, 1.0, 1.0
    for k in range(n):
        dtk = dt[di, k]
        if dtk <= 0.0:
            voltage[j, k] = _ext_advance(p, y, d, x, current[ci, k], ambient[ai, k], t_meas[ti, k], dtk, max_dt)
        else:
            if dtk != last_dt:
                n_sub, h, decay_1, decay_2, decay_d, decay_t = _ext_decays(p, dtk, max_dt)
                last_dt = dtk
            voltage[j, k] = _ext_substeps_at(p_row, 0, y_row, d_row, 0, x_row, 0, current[ci, k], ambient[ai, k],
                                             t_meas[ti, k], n_sub, h, decay_1, decay_2, decay_d, decay_t)
        temperature[j, k] = x[X_T]
        soc[j, k] = x[X_SOC]
        if record_states:
            for s in range(N_EXT_STATE):
                states[j, k, s] = x[s]
    for s in range(N_EXT_STATE):
        final[j, s] = x[s]


@njit(**_JIT)
def _simulate_ext(params, x0, dt, current, ambient, t_meas, max_dt, voltage, temperature, soc, states, record_states,
                  final):
    for j in range(params.shape[0]):
        _simulate_one_ext(j, params, x0, dt, current, ambient, t_meas, max_dt, voltage, temperature, soc, states,
                          record_states, final)


@njit(parallel=True, **_JIT)
def _simulate_ext_parallel(params, x0, dt, current, ambient, t_meas, max_dt, voltage, temperature, soc, states,
                           record_states, final):
    for j in prange(params.shape[0]):
        _simulate_one_ext(np.int64(j), params, x0, dt, current, ambient, t_meas, max_dt, voltage, temperature, soc,
                          states, record_states, final)


def _simulate_packs_extended(params, x0, dt, current, ambient, max_dt, record_states, measured_temperature,
                             parallel) -> PackTrajectory:
    params, x0, dt_, cur, amb = _pack_inputs(params, N_EXT_PARAMS, x0, N_EXT_STATE, dt, current, ambient)
    n_vec, n = params.shape[0], cur.shape[1]
    t_meas = _rows(np.nan if measured_temperature is None else measured_temperature, n_vec, n, "measured_temperature")
    voltage = np.empty((n_vec, n))
    temperature = np.empty((n_vec, n))
    soc = np.empty((n_vec, n))
    final = np.empty((n_vec, N_EXT_STATE))
    # the fit reads the surface SoC (soc - s_d) off the recorded states (problem.ExtendedPackProblem)
    states = np.empty((n_vec, n, N_EXT_STATE) if record_states else (1, 1, N_EXT_STATE))
    run = _simulate_ext_parallel if parallel else _simulate_ext
    run(params, x0, dt_, cur, amb, t_meas, float(max_dt), voltage, temperature, soc, states, bool(record_states), final)
    return PackTrajectory(voltage, temperature, soc, final, states if record_states else None)


@njit(**_JIT)
def _ocv_batch(params, soc, out):
    y = np.empty(N_OCV_KNOTS)
    d = np.empty(N_OCV_KNOTS)
    for j in range(soc.shape[0]):
        if j == 0 or params.shape[0] > 1:
            _ocv_knots(params[j if params.shape[0] > 1 else 0], y, d)
        out[j] = _ocv_eval(y, d, soc[j])


def open_circuit_voltage(params: np.ndarray, soc: np.ndarray | float) -> np.ndarray:
    """OCV (V) of extended pack vectors (N or 1, 23) at SoC (N,) — the kernel's own curve."""
    params = _params2d(params, N_EXT_PARAMS, "params")
    soc = np.ascontiguousarray(np.atleast_1d(np.asarray(soc, dtype=np.float64)))
    if params.shape[0] > 1 and soc.shape[0] == 1:
        soc = np.repeat(soc, params.shape[0])
    out = np.empty(soc.shape[0])
    _ocv_batch(params, soc, out)
    return out


def resistance_factor(params: np.ndarray, temperature_c: np.ndarray | float, soc: np.ndarray | float) -> np.ndarray:
    """f(T, SoC) of extended pack vectors (N, 23), numpy (for initial states and reports)."""
    params = np.atleast_2d(np.asarray(params, dtype=np.float64))
    t_k = np.asarray(temperature_c, dtype=np.float64) + 273.15
    soc = np.maximum(np.asarray(soc, dtype=np.float64), 0.0)
    return (np.exp(params[:, E_ER] * (1.0 / t_k - 1.0 / EXT_T_REF_K))
            * (1.0 + params[:, E_KSOC] * np.exp(-soc / params[:, E_KNEE])))


def initial_extended_state(params: np.ndarray, soc: np.ndarray | float, temperature: np.ndarray | float,
                           current: np.ndarray | float = 0.0) -> np.ndarray:
    """Extended pack states (N, 5) at a SoC and temperature with both R–C pairs and the diffusion
    depletion settled at ``current``."""
    params = _params2d(params, N_EXT_PARAMS, "params")
    n_vec = params.shape[0]
    soc = np.broadcast_to(np.asarray(soc, dtype=np.float64), (n_vec,))
    current = np.asarray(current, dtype=np.float64)
    x = np.empty((n_vec, N_EXT_STATE))
    x[:, X_SOC] = soc
    x[:, X_SD] = current * params[:, E_KD] / params[:, E_CMAX]
    f = resistance_factor(params, temperature, soc - x[:, X_SD])
    x[:, X_V1] = current * params[:, E_R1] * f
    x[:, X_V2] = current * params[:, E_R2] * f
    x[:, X_T] = temperature
    return x


def extended_rest_soc(params: np.ndarray, voltage: float, current: float, temperature: float,
                      iterations: int = 40) -> np.ndarray:
    """SoC (N,) at which each extended vector, settled at ``current`` and ``temperature``, shows
    terminal ``voltage``: V = OCV(SoC - I k_d / C_max) - I (R_0 + R_1 + R_2) f - b_ct asinh(I f / i_ct);
    bisection on [-0.3, 1.3]."""
    params = _params2d(params, N_EXT_PARAMS, "params")
    out = np.empty(params.shape[0])
    # compiled: the fit computes it for every vector on every flight, and a numpy bisection cost more
    # than the simulation of a one-vector batch
    _rest_soc_batch(params, float(voltage), float(current), float(temperature), int(iterations), out)
    return out


@njit(**_JIT)
def _rest_soc_batch(params, voltage, current, temperature, iterations, out):
    y = np.empty(N_OCV_KNOTS)
    d = np.empty(N_OCV_KNOTS)
    for j in range(params.shape[0]):
        p = params[j]
        _ocv_knots(p, y, d)
        r = p[E_R0] + p[E_R1] + p[E_R2]
        shift = current * p[E_KD] / p[E_CMAX]
        lo, hi = -0.3, 1.3
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            f = _resistance_factor(p, temperature, mid - shift)
            v = _ocv_eval(y, d, mid - shift) - current * r * f - _kinetic(p, current, temperature, mid - shift)
            if v > voltage:
                hi = mid
            else:
                lo = mid
        out[j] = 0.5 * (lo + hi)


# ---- power-driven powertrain (planner, simulated vehicle) ---------------------------------------
#
# Four packs, two in series per motor, two motors on one shaft (paper §III). PACK_NAMES order is
# (LLF20, ULA20, LRF40, URA40); the front motor's string is LLF20+LRF40, the aft one's ULA20+URA40.

N_PACKS = 4
N_MOTORS = 2
STRING_OF_PACK = np.array([0, 1, 0, 1], dtype=np.int64)

FAIL_NONE = 0
FAIL_UNDERVOLTAGE = 1
FAIL_PACK_OVERTEMP = 2
FAIL_MOTOR_OVERTEMP = 3
FAIL_POWER = 4
FAIL_DEPLETED = 5
FAILURE_NAMES = {
    FAIL_NONE: "none",
    FAIL_UNDERVOLTAGE: "pack below cut-off voltage",
    FAIL_PACK_OVERTEMP: "pack above temperature limit",
    FAIL_MOTOR_OVERTEMP: "motor above temperature limit",
    FAIL_POWER: "motors cannot deliver the power demanded",
    FAIL_DEPLETED: "pack depleted",
}

#: index of each limit in the ``limits`` vector
(L_V_CUTOFF, L_T_PACK_MAX, L_T_MOTOR_MAX) = range(3)


@njit(inline="always", **_JIT)
def _motor_current(m, q, bus_voltage, shaft_power, capability):
    """Input current of motor ``m[q]`` delivering ``shaft_power`` from ``bus_voltage``.

    V I = P + R_w I^2 + I_0' V, the smaller root; I_0' = capability * I_0 (a dead motor draws no
    no-load current). Returns -1 when no current can deliver the power (past the motor's peak).
    """
    i0 = m[q, M_I0] * capability
    if shaft_power <= 0.0:
        return i0
    c = shaft_power + i0 * bus_voltage
    disc = bus_voltage * bus_voltage - 4.0 * m[q, M_RW] * c
    if disc < 0.0:
        return -1.0
    return 2.0 * c / (bus_voltage + math.sqrt(disc))


@dataclass(frozen=True)
class PowertrainRun:
    """Result of ``simulate_powertrain``; per-step arrays only when ``record=True``."""

    final_pack_state: np.ndarray   # (N, 4, 4)
    final_motor_temp: np.ndarray   # (N, 2)
    min_pack_voltage: np.ndarray   # (N, 4)
    max_pack_temp: np.ndarray      # (N, 4)
    max_motor_temp: np.ndarray     # (N, 2)
    charge_c: np.ndarray           # (N, 4) charge drawn from each pack, C
    energy_j: np.ndarray           # (N,) electrical energy drawn, J
    fail_step: np.ndarray          # (N,) first failing sample, -1 if none
    fail_cause: np.ndarray         # (N,) FAIL_* code
    elapsed_s: np.ndarray          # (N,) simulated time (up to the failure when stopping on it)
    pack_voltage: np.ndarray | None = None   # (N, n, 4)
    pack_current: np.ndarray | None = None   # (N, n, 4)
    pack_temp: np.ndarray | None = None      # (N, n, 4)
    pack_soc: np.ndarray | None = None       # (N, n, 4)
    motor_current: np.ndarray | None = None  # (N, n, 2)
    motor_temp: np.ndarray | None = None     # (N, n, 2)
    #: with ``record_at``: the recorded samples' indices (the per-step arrays' second axis)
    recorded_steps: np.ndarray | None = None
    #: (N, P) first sample at which the pack is below its cut-off voltage or empty, -1 if none
    pack_end_step: np.ndarray | None = None
    #: (N, P) energy the pack delivered at its terminals (Σ V I dt) up to and including that
    #: sample, or over the whole run if it never ended, J
    pack_end_energy_j: np.ndarray | None = None
    #: (N, P) and (N, M): highest temperature over the samples up to and including the first
    #: failure (past it the numbers are not physical), -inf before any sample is flown
    peak_pack_temp_to_failure: np.ndarray | None = None
    peak_motor_temp_to_failure: np.ndarray | None = None

    @property
    def failed(self) -> np.ndarray:
        return self.fail_cause != FAIL_NONE
