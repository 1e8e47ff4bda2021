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
from numba import njit

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

@njit(inline="always", **_JIT)
def _soc(p, q_b):
    return 1.0 - (p[I_QMAX] - q_b) / p[I_CMAX]


@njit(inline="always", **_JIT)
def _r_cp(p, soc):
    return p[I_RCP0] + p[I_RCP1] * math.exp(p[I_RCP2] * (1.0 - soc))


@njit(inline="always", **_JIT)
def _terminal_voltage(p, x):
    return x[S_QB] / p[I_CB] - x[S_QCP] / p[I_CCP] - x[S_QS] / p[I_CS]


@njit(**_JIT)
def _pack_advance(p, x, current, ambient, dt, max_dt):
    """Advance one pack state ``x`` (in place) by ``dt`` seconds at constant terminal current."""
    if dt <= 0.0:
        return
    n_sub = 1
    if dt > max_dt:
        # capped: work bounded by samples, not by the time span (a 49.7-day log gap cost 0.25 s).
        # The R–C and thermal steps are exact at any length; only the frozen R_cp and parasitic
        # terms want short steps, and past MAX_SUBSTEPS · max_dt the held input is a guess anyway
        n_sub = min(int(math.ceil(dt / max_dt)), MAX_SUBSTEPS)
    h = dt / n_sub
    tau_s = p[I_RS] * p[I_CS]
    decay_s = math.exp(-h / tau_s)
    decay_t = math.exp(-h * p[I_H] / p[I_CT])
    for _ in range(n_sub):
        # parasitic branch across the terminals (eq. 5): i_b = i + V_p / R_p
        i_b = current + _terminal_voltage(p, x) / p[I_RP]
        # R_cp at the step's mid-point charge: q_b is exactly linear over the step, so this makes
        # the frozen-coefficient step second-order accurate near the knee at no extra cost
        r_cp = _r_cp(p, _soc(p, x[S_QB] - 0.5 * i_b * h))
        tau_cp = r_cp * p[I_CCP]
        decay_cp = math.exp(-h / tau_cp)
        # exact R–C steps towards their steady charges i_b * tau
        x[S_QS] = i_b * tau_s + (x[S_QS] - i_b * tau_s) * decay_s
        x[S_QCP] = i_b * tau_cp + (x[S_QCP] - i_b * tau_cp) * decay_cp
        x[S_QB] -= i_b * h
        # eq. 7 with the pack's resistance from the circuit: exact step towards T_inf
        heat = (p[I_RS] + r_cp) * current * current
        t_inf = ambient + heat / p[I_H]
        x[S_T] = t_inf + (x[S_T] - t_inf) * decay_t


@njit(inline="always", **_JIT)
def _motor_heat(m, current):
    # core loss scales in with the motor's load until it spins at its no-load current
    load = min(1.0, abs(current) / m[M_I0]) if m[M_I0] > 0.0 else 1.0
    return m[M_RW] * current * current + m[M_PIRON] * load


@njit(inline="always", **_JIT)
def _thermal_advance(m, temperature, current, ambient, dt):
    if dt <= 0.0:
        return temperature
    t_inf = ambient + _motor_heat(m, current) / m[M_H]
    return t_inf + (temperature - t_inf) * math.exp(-dt * m[M_H] / m[M_CT])


# ---- current-driven packs (fitting, estimation) --------------------------------------------------

@njit(**_JIT)
def _simulate_packs(params, x0, dt, current, ambient, max_dt, voltage, temperature, soc, states,
                    record_states, final):
    n_vec = params.shape[0]
    n = current.shape[1]
    x = np.empty(N_PACK_STATE)
    for j in range(n_vec):
        p = params[j]
        ci = j if current.shape[0] > 1 else 0
        ai = j if ambient.shape[0] > 1 else 0
        di = j if dt.shape[0] > 1 else 0
        for s in range(N_PACK_STATE):
            x[s] = x0[j, s]
        for k in range(n):
            _pack_advance(p, x, current[ci, k], ambient[ai, k], dt[di, k], max_dt)
            voltage[j, k] = _terminal_voltage(p, x)
            temperature[j, k] = x[S_T]
            soc[j, k] = _soc(p, x[S_QB])
            if record_states:
                for s in range(N_PACK_STATE):
                    states[j, k, s] = x[s]
        for s in range(N_PACK_STATE):
            final[j, s] = x[s]


@njit(**_JIT)
def _simulate_motor_thermal(params, temp0, dt, current, ambient, out):
    n_vec = out.shape[0]
    n = current.shape[1]
    for j in range(n_vec):
        m = params[j if params.shape[0] > 1 else 0]
        ci = j if current.shape[0] > 1 else 0
        ai = j if ambient.shape[0] > 1 else 0
        di = j if dt.shape[0] > 1 else 0
        temp = temp0[j]
        for k in range(n):
            temp = _thermal_advance(m, temp, current[ci, k], ambient[ai, k], dt[di, k])
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
    return np.ascontiguousarray(arr)


def _params2d(params: np.ndarray, width: int, name: str) -> np.ndarray:
    arr = np.ascontiguousarray(np.atleast_2d(np.asarray(params, dtype=np.float64)))
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"{name}: expected shape (N, {width}), got {np.shape(params)}")
    return arr


@dataclass(frozen=True)
class PackTrajectory:
    voltage: np.ndarray      # (N, n) terminal voltage, V
    temperature: np.ndarray  # (N, n) pack temperature, °C
    soc: np.ndarray          # (N, n) state of charge, 1
    final_state: np.ndarray  # (N, 4) PACK_STATE after the last sample
    states: np.ndarray | None = None  # (N, n, 4) if requested


def simulate_packs(params: np.ndarray, x0: np.ndarray, dt: np.ndarray, current: np.ndarray,
                   ambient: np.ndarray | float, *, max_dt: float = DEFAULT_MAX_DT,
                   record_states: bool = False) -> PackTrajectory:
    """Simulate N packs (one parameter vector each) over a current/ambient profile.

    params (N, 12) in PACK_PARAMS order; x0 (N, 4) in PACK_STATE order; dt, current, ambient
    (n,) shared or (N, n) per vector — see the module docstring for the time convention.
    """
    params = _params2d(params, N_PACK_PARAMS, "params")
    n_vec = params.shape[0]
    x0 = np.ascontiguousarray(np.broadcast_to(np.asarray(x0, dtype=np.float64), (n_vec, N_PACK_STATE)))
    cur = np.asarray(current, dtype=np.float64)
    n = cur.shape[-1]
    cur = _rows(cur, n_vec, n, "current")
    dt_ = _rows(dt, n_vec, n, "dt")
    amb = _rows(ambient, n_vec, n, "ambient")
    if np.any(dt_ < 0):
        raise ValueError("dt: time steps must be non-negative (sort and de-duplicate timestamps first)")
    voltage = np.empty((n_vec, n))
    temperature = np.empty((n_vec, n))
    soc = np.empty((n_vec, n))
    states = np.empty((n_vec, n, N_PACK_STATE) if record_states else (1, 1, N_PACK_STATE))
    final = np.empty((n_vec, N_PACK_STATE))
    _simulate_packs(params, x0, dt_, cur, amb, float(max_dt), voltage, temperature, soc, states,
                    record_states, final)
    return PackTrajectory(voltage, temperature, soc, final, states if record_states else None)


def simulate_motor_thermal(params: np.ndarray, temp0: np.ndarray | float, dt: np.ndarray,
                           current: np.ndarray, ambient: np.ndarray | float) -> np.ndarray:
    """Motor temperature (N, n), °C, from per-motor current; params (N or 1, 5) in MOTOR_PARAMS order."""
    params = _params2d(params, N_MOTOR_PARAMS, "params")
    cur = np.asarray(current, dtype=np.float64)
    n = cur.shape[-1]
    n_vec = max(params.shape[0], cur.shape[0] if cur.ndim == 2 else 1, np.size(temp0))
    t0 = np.ascontiguousarray(np.broadcast_to(np.asarray(temp0, dtype=np.float64), (n_vec,)))
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
def _motor_current(m, bus_voltage, shaft_power, capability):
    """Input current of a motor delivering ``shaft_power`` from ``bus_voltage``.

    V I = P + R_w I^2 + I_0' V, the smaller root; I_0' = capability * I_0 (a dead motor draws no
    no-load current). Returns -1 when no current can deliver the power (past the motor's peak).
    """
    i0 = m[M_I0] * capability
    if shaft_power <= 0.0:
        return i0
    c = shaft_power + i0 * bus_voltage
    disc = bus_voltage * bus_voltage - 4.0 * m[M_RW] * c
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

    @property
    def failed(self) -> np.ndarray:
        return self.fail_cause != FAIL_NONE
