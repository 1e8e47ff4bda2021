"""The power-driven powertrain for any vehicle description: P packs on B buses driving M motors.

The kernel's own compiled steps (``_pack_advance_cached``, ``_terminal_voltage``, ``_motor_current``,
``_thermal_step``; nothing is re-derived here) over a topology given as data (``Topology``,
from a description's ``gcs_pdm.vehicle.model_inputs.ModelInputs``):

* a bus joins its packs in series (bus voltage = sum, every pack carries the bus current) or in
  parallel (bus voltage = the packs' mean, each carries an equal share: identical packs);
* the motors share the demanded shaft (or thrust) power equally; a motor with power-loss fault m
  delivers (1 - m) of its share and the least-faulted motors make up the shortfall; a faulted
  rotor's drag (``fault_drag`` of its share) and its unpowered no-load loss load the others, as in
  the kernel;
* limits per pack (cut-off voltage, temperature) and per motor (temperature).

``simulate_powertrain`` below (the paper's aircraft) runs on this with ``PAPER_TOPOLOGY``; ``edge540``'s
model inputs give exactly the same numbers (tests/test_models_topology.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from gcs_pdm.models import kernel
from gcs_pdm.models.kernel import (_JIT, FAIL_DEPLETED, FAIL_MOTOR_OVERTEMP, FAIL_NONE, FAIL_PACK_OVERTEMP,
                                   FAIL_POWER, FAIL_UNDERVOLTAGE, M_I0, M_RW, N_MOTOR_PARAMS, N_PACK_PARAMS,
                                   N_PACK_STATE, S_QB, S_T, PowertrainRun, _motor_current, _rows, _soc,
                                   _terminal_voltage as _terminal_voltage_at)
from gcs_pdm.models.kernel import (N_EXT_PARAMS, N_EXT_STATE, N_OCV_KNOTS, X_SOC, _ext_advance, _ext_decays,
                                   _ext_step_lanes, _ext_substeps_at,  # extended block
                                   _ocv_knots)


@dataclass(frozen=True)
class Topology:
    """Which bus each pack and motor is on, how each bus joins its packs, and the limits."""

    bus_of_pack: np.ndarray       # (P,) int
    bus_of_motor: np.ndarray      # (M,) int
    bus_parallel: np.ndarray      # (B,) bool
    pack_cutoff_v: np.ndarray     # (P,)
    pack_max_temp_c: np.ndarray   # (P,)
    motor_max_temp_c: np.ndarray  # (M,)

    @property
    def n_packs(self) -> int:
        return len(self.bus_of_pack)

    @property
    def n_motors(self) -> int:
        return len(self.bus_of_motor)

    def with_limits(self, cutoff_v: float, pack_max_temp_c: float, motor_max_temp_c: float) -> "Topology":
        """The same topology with one limit for every pack and motor (the kernel's ``limits``)."""
        return replace(self, pack_cutoff_v=np.full(self.n_packs, float(cutoff_v)),
                       pack_max_temp_c=np.full(self.n_packs, float(pack_max_temp_c)),
                       motor_max_temp_c=np.full(self.n_motors, float(motor_max_temp_c)))


#: the paper's aircraft: (LLF20, ULA20, LRF40, URA40) in two series strings, fwd on the first, aft on the second
PAPER_TOPOLOGY = Topology(bus_of_pack=kernel.STRING_OF_PACK.copy(), bus_of_motor=np.array([0, 1], dtype=np.int64),
                          bus_parallel=np.zeros(2, dtype=bool), pack_cutoff_v=np.full(4, -np.inf),
                          pack_max_temp_c=np.full(4, np.inf), motor_max_temp_c=np.full(2, np.inf))


@njit(inline="always", **_JIT)
def _queue_one_step(n, lane_p, lane_r, lane_i, lane_amb, p_row, r, current, amb):
    """Queues pack row ``r`` (parameter row ``p_row``) for the lanes' one-step call; returns the new count."""
    lane_p[n] = p_row
    lane_r[n] = r
    lane_i[n] = current
    lane_amb[n] = amb
    return n + 1


@njit(inline="always", **_JIT)
def _motor_currents(mp, q0, f, fr, vbus, bus_of_motor, p_dem, cap, cap_total, fault_sum, f_min, n_least, inv_m,
                    fault_drag, share, imot, ibus, lane, h, energy):
    """The motors' shares of the demanded power and their currents from the bus voltages (the rules
    of the powertrain); adds each motor's current to its bus. Motor q's parameters are row
    ``q0 + q`` of ``mp``, its fault ``f[fr, q]``, its capability ``cap[lane, q]``, its current goes to
    ``imot[lane, q]`` and its bus's ``ibus[lane]`` (tables indexed, not viewed: see ``_simulate``).
    Returns (failure cause, ``energy`` plus the energy drawn over ``h``)."""
    n_motors = share.shape[0]
    p_tot = p_dem
    if p_dem > 0.0:
        # Σ f_q V_q I0_q, written as (Σ f_q V_q (I0_q / I0_0)) I0_0 so that motors sharing
        # one I_0 (the paper's) round exactly as the four-pack kernel always has
        unpowered = 0.0
        i0_ref = mp[q0, M_I0]
        for q in range(n_motors):
            if i0_ref > 0.0:
                unpowered += f[fr, q] * vbus[bus_of_motor[q]] * (mp[q0 + q, M_I0] / i0_ref)
            else:
                unpowered += f[fr, q] * vbus[bus_of_motor[q]] * mp[q0 + q, M_I0]
        if i0_ref > 0.0:
            unpowered *= i0_ref
        p_tot = p_dem * (1.0 + inv_m * fault_drag * fault_sum) + unpowered
    cause = FAIL_NONE
    if cap_total <= 0.0:
        for q in range(n_motors):
            share[q] = 0.0
        if p_dem > 0.0:
            cause = FAIL_POWER
    else:
        shortfall = p_tot
        for q in range(n_motors):
            share[q] = inv_m * p_tot * cap[lane, q]
            shortfall -= share[q]
        for q in range(n_motors):
            if f[fr, q] == f_min:
                share[q] += shortfall / n_least
    for q in range(n_motors):
        u = bus_of_motor[q]
        i_q = _motor_current(mp, q0 + q, vbus[u], share[q], cap[lane, q])
        if i_q < 0.0:
            cause = FAIL_POWER
            i_q = vbus[u] / (2.0 * mp[q0 + q, M_RW])  # the peak-power current
        imot[lane, q] = i_q
        ibus[lane, u] += i_q
        energy += vbus[u] * i_q * h
    return cause, energy


#: samples ``_simulate`` flies together, time loop outside (as ``kernel.LANES`` for the packs' driver)
LANES = 16


@njit(**_JIT)
def _simulate(pack_params, ext_params, is_ext, motor_params, x0, tm0, dt, shaft_power, fault, ambient, bus_of_pack,
              bus_of_motor, bus_parallel, cutoff_v, pack_max_t, motor_max_t, fault_drag, max_dt, stop_on_failure, slot_of_step,
              rec_v, rec_i, rec_t, rec_soc, rec_mi, rec_mt,
              final_x, final_tm, min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed,
              end_k, end_energy, peak_tp, peak_tm):
    """Every sample in blocks of ``LANES``: ``_simulate_lanes``."""
    n_packs = x0.shape[1]
    n_motors = tm0.shape[1]
    # parameter tables as rows (sample-major: sample j's pack b is row j * n_packs + b), so the steps
    # index rows instead of taking row views (two atomic reference counts each, in the inner loop)
    pp = pack_params.reshape((pack_params.shape[0] * n_packs, N_PACK_PARAMS))
    ep = ext_params.reshape((ext_params.shape[0] * n_packs, N_EXT_PARAMS))
    mp = motor_params.reshape((motor_params.shape[0] * n_motors, N_MOTOR_PARAMS))
    for j0 in range(0, x0.shape[0], LANES):
        _simulate_lanes(j0, pp, pack_params.shape[0] > 1, ep, ext_params.shape[0] > 1, is_ext, mp,
                        motor_params.shape[0] > 1, x0, tm0, dt, shaft_power, fault, ambient, bus_of_pack,
                        bus_of_motor, bus_parallel, cutoff_v, pack_max_t, motor_max_t, fault_drag, max_dt,
                        stop_on_failure, slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi, rec_mt, final_x, final_tm,
                        min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k, end_energy,
                        peak_tp, peak_tm)


@njit(**_JIT)
def _simulate_lanes(j0, pp, pp_own, ep, ep_own, is_ext, mp, mp_own, x0, tm0, dt, shaft_power, fault, ambient,
                    bus_of_pack, bus_of_motor, bus_parallel, cutoff_v, pack_max_t, motor_max_t, fault_drag, max_dt,
                    stop_on_failure, slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi, rec_mt, final_x, final_tm,
                    min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k, end_energy, peak_tp,
                    peak_tm):
    """Samples j0 … j0 + LANES - 1 (those that exist) over the profile, one time step at a time.

    One sample's step is a chain of dependent steps (bus voltage, motor currents, each pack's
    exponentials); the block's samples take each step together, pack by pack over the lanes, so
    the lanes' independent chains overlap in the processor instead of waiting on each other. Per
    sample the operations are those of one sample flown alone, in its order (the same numbers, bit
    for bit). A lane stops at its first failure with ``stop_on_failure``; the block ends when every
    lane has."""
    n = shaft_power.shape[1]
    n_packs = x0.shape[1]
    n_motors = tm0.shape[1]
    n_bus = bus_parallel.shape[0]
    nl = min(LANES, x0.shape[0] - j0)
    record = slot_of_step.shape[0] == n
    # a paper pack's state is PACK_STATE (its first four columns when the run has extended packs), an
    # extended pack's EXT_PACK_STATE; the temperature is column 3 in both (S_T == X_T). Lane l's pack
    # b is row l * n_packs + b of the state, knot and step-cache tables
    width = x0.shape[2]
    x = np.empty((LANES * n_packs, width))
    ky = np.empty((LANES * n_packs, N_OCV_KNOTS))  # an extended pack's OCV knots and slopes
    kd = np.empty((LANES * n_packs, N_OCV_KNOTS))
    step_cache = np.empty((LANES * n_packs, kernel.N_STEP_CACHE))
    # an extended pack's sub-steps and decays depend on the interval only: kept while it repeats
    ext_dt = np.empty(LANES * n_packs)
    ext_n_sub = np.empty(LANES * n_packs, dtype=np.int64)
    ext_decay = np.empty((LANES * n_packs, 5))  # sub-step length, then the R1, R2, diffusion and thermal decays
    v = np.empty(LANES * n_packs)
    i_pack = np.empty(LANES * n_packs)
    # one extended pack's lanes that take a single step together (``kernel._ext_step_lanes``: the
    # one-pack step's numbers to ~1e-14 relative, its asinh by a log)
    lane_p = np.empty(LANES, dtype=np.int64)
    lane_r = np.empty(LANES, dtype=np.int64)
    lane_i = np.empty(LANES)
    lane_amb = np.empty(LANES)
    lane_work = np.empty((8, LANES))
    tm = np.empty((LANES, n_motors))
    motor_dt = np.empty((LANES, n_motors))
    motor_decay = np.empty((LANES, n_motors))
    vbus = np.empty(n_bus)
    ibus = np.empty((LANES, n_bus))
    packs_on_bus = np.zeros(n_bus)
    for b in range(n_packs):
        packs_on_bus[bus_of_pack[b]] += 1.0
    imot = np.empty((LANES, n_motors))
    share = np.empty(n_motors)
    cap = np.empty((LANES, n_motors))
    f_min = np.empty(LANES)
    n_least = np.empty(LANES)
    cap_total = np.empty(LANES)
    fault_sum = np.empty(LANES)
    cause = np.empty(LANES, dtype=np.int64)
    t = np.zeros(LANES)
    moving = np.zeros(LANES, dtype=np.bool_)  # still flying (or, without stop_on_failure, not at the end)
    # per lane: its rows' offsets in the parameter tables
    p_row = np.empty(LANES, dtype=np.int64)
    e_row = np.empty(LANES, dtype=np.int64)
    m_row = np.empty(LANES, dtype=np.int64)
    inv_m = 1.0 / n_motors
    for lane in range(nl):
        j = j0 + lane
        p_row[lane] = (j if pp_own else 0) * n_packs
        e_row[lane] = (j if ep_own else 0) * n_packs
        m_row[lane] = (j if mp_own else 0) * n_motors
        f = fault[j if fault.shape[0] > 1 else 0]
        for b in range(n_packs):
            r = lane * n_packs + b
            for s in range(width):
                x[r, s] = x0[j, b, s]
            if is_ext[b]:
                _ocv_knots(ep[e_row[lane] + b], ky[r], kd[r])
                v[r] = _ext_advance(ep[e_row[lane] + b], ky[r], kd[r], x[r], 0.0, 0.0, np.nan, 0.0, max_dt)
                ext_dt[r] = -1.0  # no interval seen yet
            else:
                v[r] = _terminal_voltage_at(pp, p_row[lane] + b, x, r)
                kernel._reset_step_cache(pp, p_row[lane] + b, step_cache, r)
            min_v[j, b] = v[r]
            max_tp[j, b] = x[r, S_T]
            charge[j, b] = 0.0
            end_k[j, b] = -1
            end_energy[j, b] = 0.0
            peak_tp[j, b] = -np.inf
        f_min[lane] = 1.0
        cap_total[lane] = 0.0
        fault_sum[lane] = 0.0
        for q in range(n_motors):
            tm[lane, q] = tm0[j, q]
            motor_dt[lane, q] = -1.0  # no interval seen yet
            max_tm[j, q] = tm[lane, q]
            peak_tm[j, q] = -np.inf
            cap[lane, q] = 1.0 - f[q]
            cap_total[lane] += cap[lane, q]
            fault_sum[lane] += f[q]
            if f[q] < f_min[lane]:
                f_min[lane] = f[q]
        n_least[lane] = 0.0
        for q in range(n_motors):
            if f[q] == f_min[lane]:
                n_least[lane] += 1.0
        energy[j] = 0.0
        fail_k[j] = -1
        fail_cause[j] = FAIL_NONE
        moving[lane] = True
    n_moving = nl
    k = 0
    while k < n and n_moving > 0:
        # the buses and motors, lane by lane
        for lane in range(nl):
            if not moving[lane]:
                continue
            j = j0 + lane
            h = dt[j if dt.shape[0] > 1 else 0, k]
            p_dem = shaft_power[j if shaft_power.shape[0] > 1 else 0, k]
            for u in range(n_bus):
                vbus[u] = 0.0
                ibus[lane, u] = 0.0
            for b in range(n_packs):
                vbus[bus_of_pack[b]] += v[lane * n_packs + b]
            for u in range(n_bus):
                if bus_parallel[u]:
                    vbus[u] = vbus[u] / packs_on_bus[u]
            cause[lane], energy[j] = _motor_currents(
                mp, m_row[lane], fault, j if fault.shape[0] > 1 else 0, vbus, bus_of_motor, p_dem, cap,
                cap_total[lane], fault_sum[lane], f_min[lane], n_least[lane], inv_m, fault_drag, share, imot, ibus,
                lane, h, energy[j])
            for b in range(n_packs):
                u = bus_of_pack[b]
                i_pack[lane * n_packs + b] = ibus[lane, u] / packs_on_bus[u] if bus_parallel[u] else ibus[lane, u]
        # the packs, each over the lanes: the lanes' chains are independent
        for b in range(n_packs):
            n_together = 0
            for lane in range(nl):
                if not moving[lane]:
                    continue
                j = j0 + lane
                r = lane * n_packs + b
                h = dt[j if dt.shape[0] > 1 else 0, k]
                amb = ambient[j if ambient.shape[0] > 1 else 0, k]
                if is_ext[b] and h > 0.0:
                    # _ext_advance's two halves, its decays computed once per interval
                    if h != ext_dt[r]:
                        n_sub, h_sub, d1, d2, dd, dtt = _ext_decays(ep[e_row[lane] + b], h, max_dt)
                        ext_n_sub[r] = n_sub
                        ext_decay[r, 0], ext_decay[r, 1], ext_decay[r, 2] = h_sub, d1, d2
                        ext_decay[r, 3], ext_decay[r, 4] = dd, dtt
                        ext_dt[r] = h
                    if ext_n_sub[r] == 1:  # one step: with the other lanes below
                        n_together = _queue_one_step(n_together, lane_p, lane_r, lane_i, lane_amb, e_row[lane] + b,
                                                     r, i_pack[r], amb)
                    else:
                        v[r] = _ext_substeps_at(ep, e_row[lane] + b, ky, kd, r, x, r, i_pack[r], amb,
                                                np.nan, ext_n_sub[r], ext_decay[r, 0], ext_decay[r, 1],
                                                ext_decay[r, 2], ext_decay[r, 3], ext_decay[r, 4])
                elif is_ext[b]:
                    v[r] = _ext_advance(ep[e_row[lane] + b], ky[r], kd[r], x[r], i_pack[r], amb, np.nan, h, max_dt)
                elif not h <= 0.0:  # as _pack_advance_cached: a NaN interval steps (to NaN)
                    i = p_row[lane] + b
                    if h != step_cache[r, kernel.C_DT]:  # _pack_advance_cached's cache, set as it sets it
                        n_sub, h_sub = kernel._substeps(h, max_dt)
                        step_cache[r, kernel.C_NSUB] = n_sub
                        step_cache[r, kernel.C_H] = h_sub
                        step_cache[r, kernel.C_DECAY_S], step_cache[r, kernel.C_DECAY_T] = kernel._fixed_decays(
                            pp, i, h_sub, step_cache[r, kernel.C_TAU_S])
                        step_cache[r, kernel.C_DT] = h
                    if step_cache[r, kernel.C_NSUB] == 1:  # one step: with the other lanes below
                        n_together = _queue_one_step(n_together, lane_p, lane_r, lane_i, lane_amb, i, r, i_pack[r],
                                                     amb)
                    else:
                        v[r] = kernel._pack_advance_cached(pp, i, x, r, i_pack[r], amb, h, max_dt, v[r], step_cache)
            if n_together > 0 and is_ext[b]:
                _ext_step_lanes(ep, lane_p, ky, kd, x, lane_r, n_together, lane_i, lane_amb, ext_decay, v, lane_work)
            elif n_together > 0:
                kernel._pack_step_lanes(pp, lane_p, x, lane_r, n_together, lane_i, lane_amb, step_cache, v, lane_work)
        # the checks and the motors' temperatures, lane by lane
        for lane in range(nl):
            if not moving[lane]:
                continue
            j = j0 + lane
            h = dt[j if dt.shape[0] > 1 else 0, k]
            amb = ambient[j if ambient.shape[0] > 1 else 0, k]
            # a sample up to and including the first failure still counts for the peaks
            flying = fail_k[j] < 0
            slot = slot_of_step[k] if record else -1
            c = cause[lane]
            for b in range(n_packs):
                r = lane * n_packs + b
                i_b = i_pack[r]
                soc_b = x[r, X_SOC] if is_ext[b] else _soc(pp, p_row[lane] + b, x[r, S_QB])
                charge[j, b] += i_b * h
                if v[r] < min_v[j, b]:
                    min_v[j, b] = v[r]
                if x[r, S_T] > max_tp[j, b]:
                    max_tp[j, b] = x[r, S_T]
                if end_k[j, b] < 0:
                    w = v[r] * i_b
                    end_energy[j, b] += (w if math.isfinite(w) else 0.0) * h
                    if v[r] < cutoff_v[b] or soc_b <= 0.0:
                        end_k[j, b] = k
                if flying and x[r, S_T] > peak_tp[j, b]:
                    peak_tp[j, b] = x[r, S_T]
                if c == FAIL_NONE:
                    if soc_b <= 0.0:
                        c = FAIL_DEPLETED
                    elif v[r] < cutoff_v[b]:
                        c = FAIL_UNDERVOLTAGE
                    elif x[r, S_T] > pack_max_t[b]:
                        c = FAIL_PACK_OVERTEMP
                if slot >= 0:
                    rec_v[j, slot, b] = v[r]
                    rec_i[j, slot, b] = i_b
                    rec_t[j, slot, b] = x[r, S_T]
                    rec_soc[j, slot, b] = soc_b
            for q in range(n_motors):
                if not h <= 0.0:
                    if h != motor_dt[lane, q]:
                        motor_decay[lane, q] = kernel._motor_decay(mp, m_row[lane] + q, h)
                        motor_dt[lane, q] = h
                    tm[lane, q] = kernel._thermal_step(mp, m_row[lane] + q, tm[lane, q], imot[lane, q], amb,
                                                       motor_decay[lane, q])
                if tm[lane, q] > max_tm[j, q]:
                    max_tm[j, q] = tm[lane, q]
                if flying and tm[lane, q] > peak_tm[j, q]:
                    peak_tm[j, q] = tm[lane, q]
                if c == FAIL_NONE and tm[lane, q] > motor_max_t[q]:
                    c = FAIL_MOTOR_OVERTEMP
                if slot >= 0:
                    rec_mi[j, slot, q] = imot[lane, q]
                    rec_mt[j, slot, q] = tm[lane, q]
            t[lane] += h
            if c != FAIL_NONE and fail_k[j] < 0:
                fail_k[j] = k
                fail_cause[j] = c
                if stop_on_failure:
                    if record:
                        for kk in range(k + 1, n):
                            slot = slot_of_step[kk]
                            if slot < 0:
                                continue
                            for b in range(n_packs):
                                rec_v[j, slot, b] = np.nan
                                rec_i[j, slot, b] = np.nan
                                rec_t[j, slot, b] = np.nan
                                rec_soc[j, slot, b] = np.nan
                            for q in range(n_motors):
                                rec_mi[j, slot, q] = np.nan
                                rec_mt[j, slot, q] = np.nan
                    moving[lane] = False
                    n_moving -= 1
        k += 1
    for lane in range(nl):
        j = j0 + lane
        for b in range(n_packs):
            for s in range(width):
                final_x[j, b, s] = x[lane * n_packs + b, s]
        for q in range(n_motors):
            final_tm[j, q] = tm[lane, q]
        elapsed[j] = t[lane]


def simulate_vehicle(inputs: "Topology | ModelInputs", pack_params: np.ndarray | None, motor_params: np.ndarray | None, x0: np.ndarray,
                     motor_temp0: np.ndarray, dt: np.ndarray, shaft_power: np.ndarray, ambient: np.ndarray | float,
                     fault: np.ndarray | None = None, *, fault_drag: float = 0.1,
                     max_dt: float = kernel.DEFAULT_MAX_DT, stop_on_failure: bool = False,
                     record: bool = False, record_at: np.ndarray | None = None) -> PowertrainRun:
    """Fly N samples of the vehicle ``inputs`` (``ModelInputs``) through shaft-power profiles.

    pack_params (N or 1, P, 12) and motor_params (N or 1, M, 5) default to the inputs' own; x0
    (N, P, 4); motor_temp0 (N, M); dt, shaft_power [W], ambient [°C] (n,) or (N, n); fault (N or
    1, M) power-loss magnitudes in [0, 1]. Limits are the inputs' per pack and per motor.
    ``record`` keeps every sample's per-step values; ``record_at`` (increasing sample indices)
    keeps only those samples' (``recorded_steps``), which is all a coarse trajectory needs.
    """
    topo = inputs if isinstance(inputs, Topology) else inputs.topology
    n_packs, n_motors = topo.n_packs, topo.n_motors
    pp = np.asarray(inputs.pack_matrix if pack_params is None else pack_params, dtype=np.float64)
    pp = np.ascontiguousarray(pp[None] if pp.ndim == 2 else pp)
    if pp.shape[1:] != (n_packs, N_PACK_PARAMS):
        raise ValueError(f"pack_params: expected (N, {n_packs}, {N_PACK_PARAMS}), got {pp.shape}")
    mp = np.asarray(inputs.motor_matrix if motor_params is None else motor_params, dtype=np.float64)
    mp = np.ascontiguousarray(mp[None] if mp.ndim == 2 else mp)
    if mp.shape[1:] != (n_motors, N_MOTOR_PARAMS):
        raise ValueError(f"motor_params: expected (N, {n_motors}, {N_MOTOR_PARAMS}), got {mp.shape}")
    x0 = np.asarray(x0, dtype=np.float64)
    x0 = np.ascontiguousarray(x0[None] if x0.ndim == 2 else x0)
    if x0.shape[1:] != (n_packs, N_PACK_STATE):
        raise ValueError(f"x0: expected (N, {n_packs}, {N_PACK_STATE}), got {x0.shape}")
    no_ext = np.zeros((1, n_packs, N_EXT_PARAMS))
    return _run(topo, pp, no_ext, np.zeros(n_packs, dtype=np.bool_), mp, x0, motor_temp0, dt, shaft_power, ambient,
                fault, fault_drag, max_dt, stop_on_failure, record, record_at)


def _run(topo: Topology, pp: np.ndarray, ep: np.ndarray, is_ext: np.ndarray, mp: np.ndarray, x0: np.ndarray,
         motor_temp0, dt, shaft_power, ambient, fault, fault_drag: float, max_dt: float, stop_on_failure: bool,
         record: bool, record_at: np.ndarray | None) -> PowertrainRun:
    """The shared half of ``simulate_vehicle``/``simulate_vehicle_extended``: shape the profiles,
    allocate the outputs, fly ``_simulate``. Parameter and state arrays arrive checked."""
    n_packs, n_motors = topo.n_packs, topo.n_motors
    n_vec = x0.shape[0]
    tm0 = np.ascontiguousarray(np.broadcast_to(np.asarray(motor_temp0, dtype=np.float64), (n_vec, n_motors)))
    sp = np.asarray(shaft_power, dtype=np.float64)
    n = sp.shape[-1]
    sp = _rows(sp, n_vec, n, "shaft_power")
    dt_ = _rows(dt, n_vec, n, "dt")
    if np.any(dt_ < 0):
        raise ValueError("dt: time steps must be non-negative")
    amb = _rows(ambient, n_vec, n, "ambient")
    f = np.zeros((1, n_motors)) if fault is None else np.atleast_2d(np.asarray(fault, dtype=np.float64))
    if f.shape[1] != n_motors or f.shape[0] not in (1, n_vec) or np.any((f < 0) | (f > 1)):
        raise ValueError(f"fault: expected magnitudes in [0, 1] shaped (N or 1, {n_motors}), got {f!r}")
    f = np.ascontiguousarray(f)
    slot_of_step, recorded_steps = _record_slots(n, record, record_at)
    shape_rec = (n_vec, len(recorded_steps)) if recorded_steps is not None else (1, 1)
    rec = [np.empty(shape_rec + (n_packs,)) for _ in range(4)] + [np.empty(shape_rec + (n_motors,)) for _ in range(2)]
    out = dict(final_x=np.empty((n_vec, n_packs, x0.shape[2])), final_tm=np.empty((n_vec, n_motors)),
               min_v=np.empty((n_vec, n_packs)), max_tp=np.empty((n_vec, n_packs)),
               max_tm=np.empty((n_vec, n_motors)), charge=np.empty((n_vec, n_packs)), energy=np.empty(n_vec),
               fail_k=np.empty(n_vec, dtype=np.int64), fail_cause=np.empty(n_vec, dtype=np.int64),
               elapsed=np.empty(n_vec), end_k=np.empty((n_vec, n_packs), dtype=np.int64),
               end_energy=np.empty((n_vec, n_packs)), peak_tp=np.empty((n_vec, n_packs)),
               peak_tm=np.empty((n_vec, n_motors)))
    _simulate(pp, ep, np.ascontiguousarray(is_ext, dtype=np.bool_), mp, x0, tm0, dt_, sp, f, amb,
              np.ascontiguousarray(topo.bus_of_pack, dtype=np.int64),
              np.ascontiguousarray(topo.bus_of_motor, dtype=np.int64),
              np.ascontiguousarray(topo.bus_parallel, dtype=np.bool_),
              np.ascontiguousarray(topo.pack_cutoff_v, dtype=np.float64),
              np.ascontiguousarray(topo.pack_max_temp_c, dtype=np.float64),
              np.ascontiguousarray(topo.motor_max_temp_c, dtype=np.float64),
              float(fault_drag), float(max_dt), bool(stop_on_failure), slot_of_step, *rec, *out.values())
    recorded = dict(zip(("pack_voltage", "pack_current", "pack_temp", "pack_soc", "motor_current", "motor_temp"),
                        rec)) if recorded_steps is not None else {}
    if record_at is not None:
        recorded["recorded_steps"] = recorded_steps
    return PowertrainRun(out["final_x"], out["final_tm"], out["min_v"], out["max_tp"], out["max_tm"], out["charge"],
                         out["energy"], out["fail_k"], out["fail_cause"], out["elapsed"], **recorded,
                         pack_end_step=out["end_k"], pack_end_energy_j=out["end_energy"],
                         peak_pack_temp_to_failure=out["peak_tp"], peak_motor_temp_to_failure=out["peak_tm"])


def _record_slots(n: int, record: bool, record_at: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Per sample its slot in the recorded arrays (-1: not kept), and the kept samples; an
    empty slot table (and None) when nothing is recorded."""
    if record_at is not None:
        steps = np.asarray(record_at, dtype=np.int64).reshape(-1)
        if steps.size and (steps[0] < 0 or steps[-1] >= n or np.any(np.diff(steps) <= 0)):
            raise ValueError(f"record_at: expected increasing sample indices in [0, {n}), got {record_at!r}")
        slots = np.full(n, -1, dtype=np.int64)
        slots[steps] = np.arange(steps.size)
        return slots, steps
    if record:
        return np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64)
    return np.empty(0, dtype=np.int64), None


def simulate_powertrain(pack_params: np.ndarray, motor_params: np.ndarray, x0: np.ndarray,
                        motor_temp0: np.ndarray, dt: np.ndarray, shaft_power: np.ndarray,
                        ambient: np.ndarray | float, fault: np.ndarray | None = None, *,
                        limits: tuple[float, float, float] = (-np.inf, np.inf, np.inf),
                        fault_drag: float = 0.1, max_dt: float = kernel.DEFAULT_MAX_DT,
                        stop_on_failure: bool = False, record: bool = False,
                        record_at: np.ndarray | None = None) -> PowertrainRun:
    """Fly N vehicles (routes, particles, parameter vectors) through shaft-power profiles.

    pack_params (N or 1, 4, 12); motor_params (N or 1, 5); x0 (N, 4, 4) pack states; motor_temp0
    (N, 2); dt, shaft_power [W], ambient [°C] (n,) or (N, n); fault (N or 1, 2) magnitudes m in
    [0, 1] for (fwd, aft): a faulted motor delivers (1 - m) of its share of the shaft power.
    limits = (pack cut-off voltage V, pack max °C, motor max °C) decide ``fail_cause``.
    """
    pp = np.asarray(pack_params, dtype=np.float64)
    if (pp[None] if pp.ndim == 2 else pp).shape[1:] != (kernel.N_PACKS, N_PACK_PARAMS):
        raise ValueError(f"pack_params: expected (N, {kernel.N_PACKS}, {N_PACK_PARAMS}), got {pp.shape}")
    mp = kernel._params2d(motor_params, N_MOTOR_PARAMS, "motor_params")
    # both motors are one type: the same parameter vector on each
    mp = np.repeat(mp[:, None, :], kernel.N_MOTORS, axis=1)
    return simulate_vehicle(PAPER_TOPOLOGY.with_limits(*limits), pp, mp, x0, motor_temp0, dt, shaft_power, ambient,
                            fault, fault_drag=fault_drag, max_dt=max_dt, stop_on_failure=stop_on_failure,
                            record=record, record_at=record_at)


# ---- packs of the extended variant (issue 15) -------------------------------------------------------
#
# ``simulate_vehicle_extended`` flies the same vehicles with some packs on the kernel's extended
# variant (``kernel._ext_advance``: curved OCV, temperature- and SoC-dependent resistances, loss-based
# heat; docs/model.md) through the same driver, ``_simulate``. An extended pack's terminal voltage
# depends on its current, so the bus voltage a step's motor currents are solved at is each pack's
# voltage at the end of the previous step (as for the paper packs, whose R–C voltages carry the
# previous current).

def simulate_vehicle_extended(topology: Topology, pack_params: np.ndarray, ext_params: np.ndarray,
                              is_ext: np.ndarray, motor_params: np.ndarray, x0: np.ndarray, motor_temp0: np.ndarray,
                              dt: np.ndarray, shaft_power: np.ndarray, ambient: np.ndarray | float,
                              fault: np.ndarray | None = None, *, fault_drag: float = 0.1,
                              max_dt: float = kernel.DEFAULT_MAX_DT, stop_on_failure: bool = False,
                              record: bool = False, record_at: np.ndarray | None = None) -> PowertrainRun:
    """``simulate_vehicle`` with the packs flagged ``is_ext`` (P,) flown on the extended variant.

    pack_params (N or 1, P, 12) for the paper packs (rows of extended packs unused), ext_params
    (N or 1, P, N_EXT_PARAMS) for the extended ones (others unused); x0 (N, P, 5): a paper pack's
    PACK_STATE in its first four columns, an extended pack's EXT_PACK_STATE; motor_params (N or 1,
    M, 5). ``final_pack_state`` is (N, P, 5) in the same layout; the rest as ``simulate_vehicle``
    (one driver, ``_simulate``, flies both variants)."""
    topo = topology
    n_packs, n_motors = topo.n_packs, topo.n_motors

    def arr(a, width, name):
        a = np.asarray(a, dtype=np.float64)
        a = np.ascontiguousarray(a[None] if a.ndim == 2 else a)
        if a.shape[1:] != (n_packs if name != "motor_params" else n_motors, width):
            raise ValueError(f"{name}: expected (N, {n_packs if name != 'motor_params' else n_motors}, {width}), "
                             f"got {a.shape}")
        return a

    pp = arr(pack_params, N_PACK_PARAMS, "pack_params")
    ep = arr(ext_params, N_EXT_PARAMS, "ext_params")
    mp = arr(motor_params, N_MOTOR_PARAMS, "motor_params")
    x0 = arr(x0, N_EXT_STATE, "x0")
    flags = np.asarray(is_ext, dtype=np.bool_).reshape(n_packs)
    return _run(topo, pp, ep, flags, mp, x0, motor_temp0, dt, shaft_power, ambient, fault, fault_drag, max_dt,
                stop_on_failure, record, record_at)
