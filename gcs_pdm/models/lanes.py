"""The compiled powertrain driver behind ``topology.simulate_vehicle``: samples flown in lanes.

``_simulate`` flies the samples in blocks of ``LANES``, time loop outside. Every per-sample table
of a block has the lane index innermost (structure of arrays: quantity ``r`` of lane ``l`` is
``table[r, l]``), and the lanes still flying are always ``0 … n_active - 1``: a lane that stops at
its failure hands its column to the last active lane. So each stage of a time step (bus voltages,
motor currents, each pack's step, the checks, the motors' temperatures) is a loop over contiguous
lanes that LLVM compiles to SIMD instructions, and the stages with a library call (``exp``,
``log``) or a table look-up are loops of their own whose calls overlap.

Per sample the floating-point operations are those of one sample flown alone, in its order (the
same numbers, bit for bit, as the earlier lane-by-lane driver; the paper packs' as the one-pack
kernel's): a branch became a select between the two values, never a different formula.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from gcs_pdm.models import kernel
from gcs_pdm.models.lane_math import _bits_of, _float_of
from gcs_pdm.models.kernel import (_JIT, C_DECAY_S, C_DECAY_T, C_DT, C_H, C_NSUB, C_TAU_S, D_1, D_2, D_D, D_H, D_T,
                                   E_OCV0, FAIL_DEPLETED, FAIL_MOTOR_OVERTEMP, FAIL_NONE, FAIL_PACK_OVERTEMP,
                                   FAIL_POWER, FAIL_UNDERVOLTAGE, I_CB, I_CCP, I_CMAX, I_CS, I_QMAX, I_RS, M_CT, M_H,
                                   M_I0, M_PIRON, M_RW, N_EXT_DECAYS, N_EXT_WORK, N_MOTOR_PARAMS, N_OCV_CACHE,
                                   N_OCV_KNOTS, N_PACK_PARAMS, N_STEP_CACHE, O_X, S_QB, S_QCP, S_QS, S_T, X_SOC,
                                   _ext_advance, _ext_decays, _ext_step_soa, _ext_substeps_at, _ocv_knots,
                                   _pack_step_soa)

#: samples flown together, time loop outside: the Monte Carlo's chunk of 50 in one block (every stage
#: of a time step is a loop over the active lanes with a fixed cost of its own, so 16 lanes cost
#: 14 % more on the benchmark's prediction; docs/notes/2026-11-27-extended-mc.md)
LANES = 64

#: an extended pack's parameters the step reads (E_R0 … E_OCV0; the OCV increments go to its knots)
N_EXT_STEP_PARAMS = E_OCV0 + 1
# rows of the per-lane integer table
(L_SAMPLE, L_PACK_ROW, L_EXT_ROW, L_MOTOR_ROW, L_FAIL_K, L_FAIL_CAUSE) = range(6)
# rows of the per-lane float table: the power demand's drag factor, I_0 of the first motor (or 1),
# how many motors share the shortfall, whether every motor is dead, energy drawn, time flown
(F_DRAG, F_I0_SCALE, F_N_LEAST, F_DEAD, F_ENERGY, F_ELAPSED) = range(6)
# a pack's accumulators: rows b * N_ACC + a of ``acc``
(A_MIN_V, A_MAX_TP, A_CHARGE, A_END_ENERGY, A_PEAK_TP) = range(5)
N_ACC = 5
#: rows of a pack's state in the block's state table (pack b's state s: row b * XW + s), the widest
#: state (the extended pack's; a paper pack's PACK_STATE fills the first four). Every table's row
#: offsets are compile-time multiples (XW, N_ACC, N_PACK_PARAMS …): with a run-time stride LLVM can
#: neither tell two rows of one table apart nor merge them, so each lane loop needed run-time
#: overlap checks between every pair of rows, and it took its scalar loop instead of the SIMD one
#: (docs/notes/2026-11-27-extended-mc-3.md)
XW = 5
# a motor's rows q * N_MOTOR_ROWS + · of ``mot``: its MOTOR_PARAMS (M_*), then these
(MF_CAP, MF_MULT, MF_FAULT, MF_LEAST, MF_TEMP, MF_DT, MF_DECAY, MF_MAX_T, MF_PEAK_T) = range(N_MOTOR_PARAMS,
                                                                                          N_MOTOR_PARAMS + 9)
N_MOTOR_ROWS = N_MOTOR_PARAMS + 9


def _rows_of(length: int):
    """A compiled function viewing a 2-D C-contiguous array whose rows are ``length`` long as one
    whose row length is that constant, not the run-time ``shape[1]`` an argument has: an element's
    offset is then a compile-time multiple of its row, which LLVM needs to tell rows apart and
    vectorise the lane loops (see XW). The caller vouches for the length."""
    @intrinsic
    def view(typingctx, a):
        if not (isinstance(a, types.Array) and a.ndim == 2 and a.layout == "C"):
            return None

        def codegen(context, builder, sig, args):
            src = make_array(sig.args[0])(context, builder, args[0])
            dst = make_array(sig.return_type)(context, builder)
            intp = context.get_value_type(types.intp)
            item = context.get_abi_sizeof(context.get_data_type(sig.args[0].dtype))
            populate_array(dst, data=src.data, shape=[builder.extract_value(src.shape, 0), intp(length)],
                           strides=[intp(length * item), intp(item)], itemsize=src.itemsize, meminfo=src.meminfo,
                           parent=src.parent)
            return impl_ret_borrowed(context, builder, sig.return_type, dst._getvalue())
        return a(a), codegen
    return view


_lane_rows = _rows_of(LANES)
_knot_rows = _rows_of(N_OCV_KNOTS)


@njit(inline="always", **_JIT)
def _stored(x, zero):
    """``x`` with ``zero`` (a run-time 0) OR-ed into its bits: the same float. A lane loop's
    ``t[r, l] = new if c else t[r, l]`` otherwise compiles to a masked store (``vmaskmovpd``), which
    AMD's cores microcode: ~16 cycles for four lanes against one for a plain store, a quarter of the
    kernel's time in the loops that had them. LLVM sees through any identity it can fold
    (``x * 1.0``, ``bits | 0``), not through a zero it cannot know (docs/notes/2026-11-27-extended-mc-4.md)."""
    return _float_of(_bits_of(x) | zero)


@njit(**_JIT)
def _simulate(pack_params, ext_params, is_ext, motor_params, x0, tm0, dt, shaft_power, fault, ambient, bus_of_pack,
              bus_of_motor, bus_parallel, cutoff_v, pack_max_t, motor_max_t, fault_drag, max_dt, stop_on_failure,
              slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi, rec_mt,
              final_x, final_tm, min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed,
              end_k, end_energy, peak_tp, peak_tm):
    """Every sample in blocks of ``LANES``: ``_simulate_lanes``."""
    n_packs = x0.shape[1]
    n_motors = tm0.shape[1]
    # parameter tables as rows (sample-major: sample j's pack b is row j * n_packs + b)
    pp = pack_params.reshape((pack_params.shape[0] * n_packs, N_PACK_PARAMS))
    ep = ext_params.reshape((ext_params.shape[0] * n_packs, ext_params.shape[2]))
    mp = motor_params.reshape((motor_params.shape[0] * n_motors, N_MOTOR_PARAMS))
    for j0 in range(0, x0.shape[0], LANES):
        _simulate_lanes(j0, pp, pack_params.shape[0] > 1, ep, ext_params.shape[0] > 1, is_ext, mp,
                        motor_params.shape[0] > 1, x0, tm0, dt, shaft_power, fault, ambient, bus_of_pack,
                        bus_of_motor, bus_parallel, cutoff_v, pack_max_t, motor_max_t, fault_drag, max_dt,
                        stop_on_failure, slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi, rec_mt, final_x, final_tm,
                        min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k, end_energy,
                        peak_tp, peak_tm)


@njit(inline="always", **_JIT)
def _lane_inputs(profile, own, k, lane_int, na, out):
    """Step ``k`` of a profile for each active lane: its sample's row, or the one shared row."""
    if own:
        for l in range(na):
            out[l] = profile[lane_int[L_SAMPLE, l], k]
    else:
        shared = profile[0, k]
        for l in range(na):
            out[l] = shared


@njit(**_JIT)
def _swap_lanes(a, l1, l2):
    for r in range(a.shape[0]):
        a[r, l1], a[r, l2] = a[r, l2], a[r, l1]


@njit(**_JIT)
def _simulate_lanes(j0, pp, pp_own, ep, ep_own, is_ext, mp, mp_own, x0, tm0, dt, shaft_power, fault, ambient,
                    bus_of_pack, bus_of_motor, bus_parallel, cutoff_v, pack_max_t, motor_max_t, fault_drag, max_dt,
                    stop_on_failure, slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi, rec_mt, final_x, final_tm,
                    min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k, end_energy, peak_tp,
                    peak_tm):
    """Samples j0 … j0 + LANES - 1 (those that exist) over the profile, one time step at a time.

    A lane stops at its first failure with ``stop_on_failure`` (its results are written then and
    the last active lane takes its column); the block ends when every lane has, or at the
    profile's end. This allocates the block's tables and starts its lanes; ``_fly_lanes`` flies them."""
    n_packs = x0.shape[1]
    n_motors = tm0.shape[1]
    n_bus = bus_parallel.shape[0]
    width = x0.shape[2]  # a paper pack's PACK_STATE in its first four rows, an extended pack's EXT_PACK_STATE
    if width > XW:
        raise ValueError("a pack state wider than the block's state rows (XW)")
    # ---- the block's tables, lane innermost; every one with per-lane state is swapped with the lane
    lane_int = np.empty((6, LANES), dtype=np.int64)
    lane_f = np.empty((6, LANES))
    xs = np.empty((n_packs * XW, LANES))                   # pack b's state s: row b * XW + s
    v = np.empty((n_packs, LANES))                         # terminal voltages
    pt = np.empty((n_packs * N_PACK_PARAMS, LANES))        # paper packs' parameters
    cache = np.empty((n_packs * N_STEP_CACHE, LANES))      # and their step caches (kernel._pack_advance_cached)
    et = np.empty((n_packs * N_EXT_STEP_PARAMS, LANES))    # extended packs' parameters
    decay = np.empty((n_packs * N_EXT_DECAYS, LANES))      # and their interval's decays (kernel._ext_decays),
    ext_dt = np.empty((n_packs, LANES))                    # for this interval,
    ext_n_sub = np.empty((n_packs, LANES), dtype=np.int64)  # in so many sub-steps
    knot_row = np.empty((n_packs, LANES), dtype=np.int64)  # row of the OCV knot tables below
    ocv_c = np.empty((n_packs * N_OCV_CACHE, LANES))       # and the knot interval each pack last used
    acc = np.empty((N_ACC * n_packs, LANES))
    pack_end = np.empty((n_packs, LANES), dtype=np.int64)
    mot = np.empty((n_motors * N_MOTOR_ROWS, LANES))
    # not swapped: tables a lane keeps its row of (the knots) and each step's scratch
    ky = np.empty((LANES * n_packs, N_OCV_KNOTS))
    kd = np.empty((LANES * n_packs, N_OCV_KNOTS))
    h_l = np.empty(LANES)
    power_l = np.empty(LANES)
    amb_l = np.empty(LANES)
    unpowered = np.empty(LANES)
    p_tot = np.empty(LANES)
    shortfall = np.empty(LANES)
    cause = np.empty(LANES, dtype=np.int64)
    flying = np.empty(LANES, dtype=np.bool_)
    simple = np.empty(LANES, dtype=np.bool_)
    vbus = np.empty((n_bus, LANES))
    ibus = np.empty((n_bus, LANES))
    share = np.empty((n_motors, LANES))
    imot = np.empty((n_motors, LANES))
    ipack = np.empty((n_packs, LANES))
    soc = np.empty((n_packs, LANES))
    work = np.empty((N_EXT_WORK, LANES))
    x_row = np.empty((1, width))  # one lane's pack state as a row, for the one-pack steps
    cache_row = np.empty((1, N_STEP_CACHE))
    packs_on_bus = np.zeros(n_bus)
    for b in range(n_packs):
        packs_on_bus[bus_of_pack[b]] += 1.0
    na = min(LANES, x0.shape[0] - j0)  # active lanes
    for lane in range(na):
        _start_lane(lane, j0 + lane, pp, pp_own, ep, ep_own, is_ext, mp, mp_own, x0, tm0, fault, fault_drag, max_dt,
                    lane_int, lane_f, xs, v, pt, cache, et, ext_dt, knot_row, ocv_c, acc, pack_end, mot, ky, kd, x_row)
    _fly_lanes(na, pp, ep, is_ext, dt, shaft_power, ambient, bus_of_pack, bus_of_motor, bus_parallel, cutoff_v,
               pack_max_t, motor_max_t, max_dt, stop_on_failure, slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi,
               rec_mt, final_x, final_tm, min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k,
               end_energy, peak_tp, peak_tm, lane_int, lane_f, xs, v, pt, cache, et, decay, ext_dt, ext_n_sub,
               knot_row, ocv_c, acc, pack_end, mot, ky, kd, h_l, power_l, amb_l, unpowered, p_tot, shortfall, cause,
               flying, simple, vbus, ibus, share, imot, ipack, soc, work, x_row, cache_row, packs_on_bus)


@njit(_nrt=False, **_JIT)
def _fly_lanes(na, pp, ep, is_ext, dt, shaft_power, ambient, bus_of_pack, bus_of_motor, bus_parallel, cutoff_v,
               pack_max_t, motor_max_t, max_dt, stop_on_failure, slot_of_step, rec_v, rec_i, rec_t, rec_soc, rec_mi,
               rec_mt, final_x, final_tm, min_v, max_tp, max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k,
               end_energy, peak_tp, peak_tm, lane_int, lane_f, xs, v, pt, cache, et, decay, ext_dt, ext_n_sub,
               knot_row, ocv_c, acc, pack_end, mot, ky, kd, h_l, power_l, amb_l, unpowered, p_tot, shortfall, cause,
               flying, simple, vbus, ibus, share, imot, ipack, soc, work, x_row, cache_row, packs_on_bus):
    """The block's time loop over tables ``_simulate_lanes`` allocated and filled (compiled without
    numba's reference counting: nothing here allocates, and the counts' atomic increments on every
    table passed to an inlined step cost ~10 % of the kernel; docs/notes/2026-11-27-extended-mc-4.md)."""
    n = shaft_power.shape[1]
    n_packs = xs.shape[0] // XW
    n_motors = mot.shape[0] // N_MOTOR_ROWS
    n_bus = bus_parallel.shape[0]
    width = x_row.shape[1]
    record = slot_of_step.shape[0] == n
    dt_own, power_own, ambient_own = dt.shape[0] > 1, shaft_power.shape[0] > 1, ambient.shape[0] > 1
    inv_m = 1.0 / n_motors
    if lane_f.shape[1] != LANES or lane_int.shape[1] != LANES or ky.shape[1] != N_OCV_KNOTS:
        raise ValueError("_fly_lanes: block tables of LANES columns, knot tables of N_OCV_KNOTS")
    # the tables' row length as a compile-time constant again (an argument's is not: see XW)
    lane_int = _lane_rows(lane_int)
    lane_f = _lane_rows(lane_f)
    xs = _lane_rows(xs)
    v = _lane_rows(v)
    pt = _lane_rows(pt)
    cache = _lane_rows(cache)
    et = _lane_rows(et)
    decay = _lane_rows(decay)
    ext_dt = _lane_rows(ext_dt)
    ext_n_sub = _lane_rows(ext_n_sub)
    knot_row = _lane_rows(knot_row)
    ocv_c = _lane_rows(ocv_c)
    acc = _lane_rows(acc)
    pack_end = _lane_rows(pack_end)
    mot = _lane_rows(mot)
    vbus = _lane_rows(vbus)
    ibus = _lane_rows(ibus)
    share = _lane_rows(share)
    imot = _lane_rows(imot)
    ipack = _lane_rows(ipack)
    soc = _lane_rows(soc)
    work = _lane_rows(work)
    ky, kd = _knot_rows(ky), _knot_rows(kd)
    zero = np.int64(xs.shape[0] < 0)  # 0, which the compiler cannot know: see _stored
    k = 0
    while k < n and na > 0:
        _lane_inputs(dt, dt_own, k, lane_int, na, h_l)
        _lane_inputs(shaft_power, power_own, k, lane_int, na, power_l)
        _lane_inputs(ambient, ambient_own, k, lane_int, na, amb_l)
        # ---- the buses and the motors' currents
        for u in range(n_bus):
            for l in range(na):
                vbus[u, l] = 0.0
                ibus[u, l] = 0.0
        for b in range(n_packs):
            u = bus_of_pack[b]
            for l in range(na):
                vbus[u, l] += v[b, l]
        for u in range(n_bus):
            if bus_parallel[u]:
                for l in range(na):
                    vbus[u, l] = vbus[u, l] / packs_on_bus[u]
        # the power to deliver: the demand, the faulted rotors' drag and the unpowered share of the
        # motors' no-load loss, Σ f_q V_q (I0_q / I0_0) I0_0 (so motors sharing one I_0 round as the
        # paper's kernel always has)
        for l in range(na):
            unpowered[l] = 0.0
        for q in range(n_motors):
            u = bus_of_motor[q]
            o = q * N_MOTOR_ROWS
            for l in range(na):
                unpowered[l] += mot[o + MF_FAULT, l] * vbus[u, l] * mot[o + MF_MULT, l]
        for l in range(na):
            unpowered[l] = unpowered[l] * lane_f[F_I0_SCALE, l]
            p_tot[l] = power_l[l] * lane_f[F_DRAG, l] + unpowered[l] if power_l[l] > 0.0 else power_l[l]
            shortfall[l] = p_tot[l]
            cause[l] = FAIL_POWER if (lane_f[F_DEAD, l] != 0.0) & (power_l[l] > 0.0) else FAIL_NONE
        # equal shares of what the motors can deliver; the least-faulted make up the shortfall
        for q in range(n_motors):
            o = q * N_MOTOR_ROWS
            for l in range(na):
                s = inv_m * p_tot[l] * mot[o + MF_CAP, l]
                share[q, l] = s
                shortfall[l] -= s
        for q in range(n_motors):
            o = q * N_MOTOR_ROWS
            for l in range(na):
                s = share[q, l]
                # every value a select picks from is computed on every lane: a division or a load
                # under a condition makes LLVM mask the loop's loads and stores (see _stored)
                made_up = s + shortfall[l] / lane_f[F_N_LEAST, l]
                s = made_up if mot[o + MF_LEAST, l] != 0.0 else s
                share[q, l] = _stored(0.0 if lane_f[F_DEAD, l] != 0.0 else s, zero)
        # each motor's current (kernel._motor_current: V I = P + R_w I^2 + I_0' V, the smaller root;
        # past the motor's peak, its peak-power current and a failure)
        for q in range(n_motors):
            u = bus_of_motor[q]
            o = q * N_MOTOR_ROWS
            for l in range(na):
                vb = vbus[u, l]
                s = share[q, l]
                i0 = mot[o + M_I0, l] * mot[o + MF_CAP, l]
                c = s + i0 * vb
                disc = vb * vb - 4.0 * mot[o + M_RW, l] * c
                i_q = 2.0 * c / (vb + math.sqrt(disc))
                i_q = i0 if s <= 0.0 else (-1.0 if disc < 0.0 else i_q)
                past_peak = i_q < 0.0
                was = cause[l]  # loaded on every lane, not under the condition
                cause[l] = (FAIL_POWER if past_peak else was) | zero
                at_peak = vb / (2.0 * mot[o + M_RW, l])
                i_q = at_peak if past_peak else i_q
                imot[q, l] = i_q
                ibus[u, l] += i_q
                lane_f[F_ENERGY, l] += vb * i_q * h_l[l]
        for b in range(n_packs):
            u = bus_of_pack[b]
            if bus_parallel[u]:
                for l in range(na):
                    ipack[b, l] = ibus[u, l] / packs_on_bus[u]
            else:
                for l in range(na):
                    ipack[b, l] = ibus[u, l]
        # ---- the packs, each over the lanes
        for b in range(n_packs):
            if is_ext[b]:
                _ext_packs_step(b, na, ep, et, ky, kd, knot_row, ocv_c, xs, width, decay, ext_dt, ext_n_sub, lane_int,
                                h_l, ipack, amb_l, v, max_dt, simple, work, x_row)
            else:
                _paper_packs_step(b, na, pp, pt, xs, width, cache, lane_int, h_l, ipack, amb_l, v, max_dt, simple,
                                  work, x_row, cache_row)
        # ---- the checks and the motors' temperatures
        for l in range(na):
            flying[l] = lane_int[L_FAIL_K, l] < 0  # a sample up to and including its first failure
        for b in range(n_packs):
            o = b * XW
            if is_ext[b]:
                for l in range(na):
                    soc[b, l] = xs[o + X_SOC, l]
            else:
                po = b * N_PACK_PARAMS
                for l in range(na):
                    soc[b, l] = 1.0 - (pt[po + I_QMAX, l] - xs[o + S_QB, l]) / pt[po + I_CMAX, l]
            # three loops, each writing one table (fewer run-time overlap checks: see XW)
            a = b * N_ACC
            for l in range(na):  # the accumulators
                vv = v[b, l]
                i_b = ipack[b, l]
                temp = xs[o + S_T, l]
                h = h_l[l]
                acc[a + A_CHARGE, l] += i_b * h
                m = acc[a + A_MIN_V, l]
                acc[a + A_MIN_V, l] = _stored(vv if vv < m else m, zero)
                m = acc[a + A_MAX_TP, l]
                acc[a + A_MAX_TP, l] = _stored(temp if temp > m else m, zero)
                w = vv * i_b
                e = acc[a + A_END_ENERGY, l]
                acc[a + A_END_ENERGY, l] = _stored(e + (w if math.isfinite(w) else 0.0) * h if pack_end[b, l] < 0 else e,
                                                   zero)
                m = acc[a + A_PEAK_TP, l]
                acc[a + A_PEAK_TP, l] = _stored(temp if flying[l] & (temp > m) else m, zero)
            cut, t_max = cutoff_v[b], pack_max_t[b]
            for l in range(na):  # its end: cut-off or empty
                pe = pack_end[b, l]
                pack_end[b, l] = (k if (pe < 0) & ((v[b, l] < cut) | (soc[b, l] <= 0.0)) else pe) | zero
            for l in range(na):  # the first failure's cause
                c = FAIL_PACK_OVERTEMP if xs[o + S_T, l] > t_max else FAIL_NONE
                c = FAIL_UNDERVOLTAGE if v[b, l] < cut else c
                c = FAIL_DEPLETED if soc[b, l] <= 0.0 else c
                cause[l] = (c if cause[l] == FAIL_NONE else cause[l]) | zero
        for q in range(n_motors):
            o = q * N_MOTOR_ROWS
            n_new = 0  # the decay's exp only when the interval changes (kernel._motor_decay)
            for l in range(na):
                n_new += (not h_l[l] <= 0.0) & (h_l[l] != mot[o + MF_DT, l])
            if n_new:
                for l in range(na):
                    h = h_l[l]
                    if not h <= 0.0 and h != mot[o + MF_DT, l]:
                        mot[o + MF_DECAY, l] = math.exp(-h * mot[o + M_H, l] / mot[o + M_CT, l])
                        mot[o + MF_DT, l] = h
            for l in range(na):  # kernel._thermal_step
                i_q = imot[q, l]
                i0 = mot[o + M_I0, l]
                ratio = abs(i_q) / i0
                load = min(1.0, ratio) if i0 > 0.0 else 1.0
                heat = mot[o + M_RW, l] * i_q * i_q + mot[o + M_PIRON, l] * load
                t_inf = amb_l[l] + heat / mot[o + M_H, l]
                temp = mot[o + MF_TEMP, l]
                temp = temp if h_l[l] <= 0.0 else t_inf + (temp - t_inf) * mot[o + MF_DECAY, l]
                mot[o + MF_TEMP, l] = _stored(temp, zero)
                m = mot[o + MF_MAX_T, l]
                mot[o + MF_MAX_T, l] = _stored(temp if temp > m else m, zero)
                m = mot[o + MF_PEAK_T, l]
                mot[o + MF_PEAK_T, l] = _stored(temp if flying[l] & (temp > m) else m, zero)
            t_max = motor_max_t[q]
            for l in range(na):
                over = (cause[l] == FAIL_NONE) & (mot[o + MF_TEMP, l] > t_max)
                cause[l] = (FAIL_MOTOR_OVERTEMP if over else cause[l]) | zero
        slot = slot_of_step[k] if record else -1
        if slot >= 0:
            for l in range(na):
                j = lane_int[L_SAMPLE, l]
                for b in range(n_packs):
                    rec_v[j, slot, b] = v[b, l]
                    rec_i[j, slot, b] = ipack[b, l]
                    rec_t[j, slot, b] = xs[b * XW + S_T, l]
                    rec_soc[j, slot, b] = soc[b, l]
                for q in range(n_motors):
                    rec_mi[j, slot, q] = imot[q, l]
                    rec_mt[j, slot, q] = mot[q * N_MOTOR_ROWS + MF_TEMP, l]
        for l in range(na):
            lane_f[F_ELAPSED, l] += h_l[l]
            first = (cause[l] != FAIL_NONE) & (lane_int[L_FAIL_K, l] < 0)
            lane_int[L_FAIL_CAUSE, l] = (cause[l] if first else lane_int[L_FAIL_CAUSE, l]) | zero
            lane_int[L_FAIL_K, l] = (k if first else lane_int[L_FAIL_K, l]) | zero
        if stop_on_failure:
            # downwards, so the lane moved into a freed column has been looked at already
            for l in range(na - 1, -1, -1):
                if lane_int[L_FAIL_K, l] != k:
                    continue
                j = lane_int[L_SAMPLE, l]
                if record:
                    for kk in range(k + 1, n):
                        s = slot_of_step[kk]
                        if s < 0:
                            continue
                        for b in range(n_packs):
                            rec_v[j, s, b] = np.nan
                            rec_i[j, s, b] = np.nan
                            rec_t[j, s, b] = np.nan
                            rec_soc[j, s, b] = np.nan
                        for q in range(n_motors):
                            rec_mi[j, s, q] = np.nan
                            rec_mt[j, s, q] = np.nan
                _finish_lane(l, lane_int, lane_f, xs, width, acc, pack_end, mot, final_x, final_tm, min_v, max_tp,
                             max_tm, charge, energy, fail_k, fail_cause, elapsed, end_k, end_energy, peak_tp, peak_tm)
                na -= 1
                if l != na:
                    for a in (lane_f, xs, v, pt, cache, et, decay, ext_dt, ocv_c, acc, mot):
                        _swap_lanes(a, l, na)
                    for a in (lane_int, ext_n_sub, knot_row, pack_end):
                        _swap_lanes(a, l, na)
        k += 1
    for l in range(na):
        _finish_lane(l, lane_int, lane_f, xs, width, acc, pack_end, mot, final_x, final_tm, min_v, max_tp, max_tm,
                     charge, energy, fail_k, fail_cause, elapsed, end_k, end_energy, peak_tp, peak_tm)


@njit(inline="always", **_JIT)
def _paper_packs_step(b, na, pp, pt, xs, width, cache, lane_int, h_l, ipack, amb_l, v, max_dt, simple, work, x_row,
                      cache_row):
    """Paper pack ``b`` of every active lane over one interval (``kernel._pack_advance_cached``'s
    cache set as it sets it): the lanes that take one step together, others one by one."""
    po, o, co = b * N_PACK_PARAMS, b * XW, b * N_STEP_CACHE
    n_new = 0  # lanes whose interval changed (a SIMD count; their caches are set below)
    for l in range(na):  # as _pack_advance_cached: a NaN interval steps (to NaN)
        n_new += (not h_l[l] <= 0.0) & (h_l[l] != cache[co + C_DT, l])
    if n_new:
        for l in range(na):
            h = h_l[l]
            if not h <= 0.0 and h != cache[co + C_DT, l]:
                n_sub, h_sub = kernel._substeps(h, max_dt)
                cache[co + C_NSUB, l] = n_sub
                cache[co + C_H, l] = h_sub
                cache[co + C_DECAY_S, l], cache[co + C_DECAY_T, l] = kernel._fixed_decays(
                    pp, lane_int[L_PACK_ROW, l] + b, h_sub, cache[co + C_TAU_S, l])
                cache[co + C_DT, l] = h
    n_simple = 0
    for l in range(na):
        one = (not h_l[l] <= 0.0) & (cache[co + C_NSUB, l] == 1)
        simple[l] = one
        n_simple += one
    if n_simple == na:
        _pack_step_soa(pt, po, xs, o, cache, co, b, 0, na, ipack, amb_l, v, work)
        return
    for l in range(na):
        if simple[l]:
            _pack_step_soa(pt, po, xs, o, cache, co, b, l, l + 1, ipack, amb_l, v, work)
        elif not h_l[l] <= 0.0:  # sub-steps
            for s in range(width):
                x_row[0, s] = xs[o + s, l]
            for c in range(N_STEP_CACHE):
                cache_row[0, c] = cache[co + c, l]
            v[b, l] = kernel._pack_advance_cached(pp, lane_int[L_PACK_ROW, l] + b, x_row, 0, ipack[b, l], amb_l[l],
                                                  h_l[l], max_dt, v[b, l], cache_row)
            for s in range(width):
                xs[o + s, l] = x_row[0, s]


@njit(inline="always", **_JIT)
def _ext_packs_step(b, na, ep, et, ky, kd, knot_row, ocv_c, xs, width, decay, ext_dt, ext_n_sub, lane_int, h_l, ipack,
                    amb_l, v, max_dt, simple, work, x_row):
    """Extended pack ``b`` of every active lane over one interval (``kernel._ext_advance``, its
    decays computed once per interval): the lanes that take one step together, others one by one."""
    eo, o, do, oo = b * N_EXT_STEP_PARAMS, b * XW, b * N_EXT_DECAYS, b * N_OCV_CACHE
    n_new = 0  # lanes whose interval changed (a SIMD count; their decays are computed below)
    for l in range(na):
        n_new += (h_l[l] > 0.0) & (h_l[l] != ext_dt[b, l])
    if n_new:
        for l in range(na):
            h = h_l[l]
            if h > 0.0 and h != ext_dt[b, l]:
                n_sub, h_sub, d1, d2, dd, dtt = _ext_decays(ep[lane_int[L_EXT_ROW, l] + b], h, max_dt)
                ext_n_sub[b, l] = n_sub
                decay[do + D_H, l], decay[do + D_1, l], decay[do + D_2, l] = h_sub, d1, d2
                decay[do + D_D, l], decay[do + D_T, l] = dd, dtt
                ext_dt[b, l] = h
    n_simple = 0
    for l in range(na):
        one = (h_l[l] > 0.0) & (ext_n_sub[b, l] == 1)
        simple[l] = one
        n_simple += one
    if n_simple == na:
        _ext_step_soa(et, eo, ky, kd, knot_row, ocv_c, oo, xs, o, decay, do, b, 0, na, ipack, amb_l, v, work)
        return
    for l in range(na):
        if simple[l]:
            _ext_step_soa(et, eo, ky, kd, knot_row, ocv_c, oo, xs, o, decay, do, b, l, l + 1, ipack, amb_l, v, work)
            continue
        for s in range(width):
            x_row[0, s] = xs[o + s, l]
        i, r = lane_int[L_EXT_ROW, l] + b, knot_row[b, l]
        if h_l[l] > 0.0:  # sub-steps
            v[b, l] = _ext_substeps_at(ep, i, ky, kd, r, x_row, 0, ipack[b, l], amb_l[l], np.nan, ext_n_sub[b, l],
                                       decay[do + D_H, l], decay[do + D_1, l], decay[do + D_2, l],
                                       decay[do + D_D, l], decay[do + D_T, l])
        else:
            v[b, l] = _ext_advance(ep[i], ky[r], kd[r], x_row[0], ipack[b, l], amb_l[l], np.nan, h_l[l], max_dt)
        for s in range(width):
            xs[o + s, l] = x_row[0, s]


@njit(inline="always", **_JIT)
def _start_lane(l, j, pp, pp_own, ep, ep_own, is_ext, mp, mp_own, x0, tm0, fault, fault_drag, max_dt,
                lane_int, lane_f, xs, v, pt, cache, et, ext_dt, knot_row, ocv_c, acc, pack_end, mot, ky, kd, x_row):
    """Lane ``l`` takes sample ``j``: its parameters, initial state and voltages, and its accumulators.
    (At most 30 arguments: CPython passes more as a tuple, which numba cannot inline.)"""
    n_packs, n_motors, width = x0.shape[1], tm0.shape[1], x0.shape[2]
    inv_m = 1.0 / n_motors
    lane_int[L_SAMPLE, l] = j
    lane_int[L_PACK_ROW, l] = (j if pp_own else 0) * n_packs
    lane_int[L_EXT_ROW, l] = (j if ep_own else 0) * n_packs
    lane_int[L_MOTOR_ROW, l] = (j if mp_own else 0) * n_motors
    lane_int[L_FAIL_K, l] = -1
    lane_int[L_FAIL_CAUSE, l] = FAIL_NONE
    for b in range(n_packs):
        o, po = b * XW, b * N_PACK_PARAMS
        i = lane_int[L_PACK_ROW, l] + b
        for s in range(width):
            xs[o + s, l] = x0[j, b, s]
        for c in range(N_PACK_PARAMS):
            pt[po + c, l] = pp[i, c]
        if is_ext[b]:
            e, r = lane_int[L_EXT_ROW, l] + b, l * n_packs + b
            for c in range(N_EXT_STEP_PARAMS):
                et[b * N_EXT_STEP_PARAMS + c, l] = ep[e, c]
            knot_row[b, l] = r
            _ocv_knots(ep[e], ky[r], kd[r])
            for s in range(width):
                x_row[0, s] = x0[j, b, s]
            v[b, l] = _ext_advance(ep[e], ky[r], kd[r], x_row[0], 0.0, 0.0, np.nan, 0.0, max_dt)
            ext_dt[b, l] = -1.0  # no interval seen yet
            ocv_c[b * N_OCV_CACHE + O_X, l] = np.inf  # no knot interval cached yet
        else:
            v[b, l] = (xs[o + S_QB, l] / pt[po + I_CB, l] - xs[o + S_QCP, l] / pt[po + I_CCP, l]
                       - xs[o + S_QS, l] / pt[po + I_CS, l])
            cache[b * N_STEP_CACHE + C_DT, l] = -1.0  # no interval seen yet (kernel._reset_step_cache)
            cache[b * N_STEP_CACHE + C_TAU_S, l] = pt[po + I_RS, l] * pt[po + kernel.I_CS, l]
        acc[b * N_ACC + A_MIN_V, l] = v[b, l]
        acc[b * N_ACC + A_MAX_TP, l] = xs[o + S_T, l]
        acc[b * N_ACC + A_CHARGE, l] = 0.0
        acc[b * N_ACC + A_END_ENERGY, l] = 0.0
        acc[b * N_ACC + A_PEAK_TP, l] = -np.inf
        pack_end[b, l] = -1
    f = fault[j if fault.shape[0] > 1 else 0]
    m0 = lane_int[L_MOTOR_ROW, l]
    i0_ref = mp[m0, M_I0]
    f_min, cap_total, fault_sum = 1.0, 0.0, 0.0
    for q in range(n_motors):
        o = q * N_MOTOR_ROWS
        for c in range(N_MOTOR_PARAMS):
            mot[o + c, l] = mp[m0 + q, c]
        mot[o + MF_FAULT, l] = f[q]
        mot[o + MF_CAP, l] = 1.0 - f[q]
        cap_total += mot[o + MF_CAP, l]
        fault_sum += f[q]
        if f[q] < f_min:
            f_min = f[q]
        mot[o + MF_MULT, l] = mp[m0 + q, M_I0] / i0_ref if i0_ref > 0.0 else mp[m0 + q, M_I0]
        mot[o + MF_TEMP, l] = tm0[j, q]
        mot[o + MF_DT, l] = -1.0  # no interval seen yet
        mot[o + MF_MAX_T, l] = tm0[j, q]
        mot[o + MF_PEAK_T, l] = -np.inf
    n_least = 0.0
    for q in range(n_motors):
        least = f[q] == f_min
        mot[q * N_MOTOR_ROWS + MF_LEAST, l] = 1.0 if least else 0.0
        n_least += 1.0 if least else 0.0
    lane_f[F_DRAG, l] = 1.0 + inv_m * fault_drag * fault_sum
    lane_f[F_I0_SCALE, l] = i0_ref if i0_ref > 0.0 else 1.0
    lane_f[F_N_LEAST, l] = n_least
    lane_f[F_DEAD, l] = 1.0 if cap_total <= 0.0 else 0.0
    lane_f[F_ENERGY, l] = 0.0
    lane_f[F_ELAPSED, l] = 0.0


@njit(inline="always", **_JIT)
def _finish_lane(l, lane_int, lane_f, xs, width, acc, pack_end, mot, final_x, final_tm, min_v, max_tp, max_tm, charge,
                 energy, fail_k, fail_cause, elapsed, end_k, end_energy, peak_tp, peak_tm):
    """Lane ``l``'s results to its sample's rows of the outputs."""
    j = lane_int[L_SAMPLE, l]
    n_packs, n_motors = final_x.shape[1], final_tm.shape[1]
    for b in range(n_packs):
        for s in range(width):
            final_x[j, b, s] = xs[b * XW + s, l]
        min_v[j, b] = acc[b * N_ACC + A_MIN_V, l]
        max_tp[j, b] = acc[b * N_ACC + A_MAX_TP, l]
        charge[j, b] = acc[b * N_ACC + A_CHARGE, l]
        end_energy[j, b] = acc[b * N_ACC + A_END_ENERGY, l]
        peak_tp[j, b] = acc[b * N_ACC + A_PEAK_TP, l]
        end_k[j, b] = pack_end[b, l]
    for q in range(n_motors):
        o = q * N_MOTOR_ROWS
        final_tm[j, q] = mot[o + MF_TEMP, l]
        max_tm[j, q] = mot[o + MF_MAX_T, l]
        peak_tm[j, q] = mot[o + MF_PEAK_T, l]
    energy[j] = lane_f[F_ENERGY, l]
    elapsed[j] = lane_f[F_ELAPSED, l]
    fail_k[j] = lane_int[L_FAIL_K, l]
    fail_cause[j] = lane_int[L_FAIL_CAUSE, l]
