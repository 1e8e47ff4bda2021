"""The power-driven powertrain for any vehicle description: P packs on B buses driving M motors.

The kernel's steps over a topology given as data (``Topology``, from a description's
``gcs_pdm.vehicle.model_inputs.ModelInputs``), flown by the compiled driver in
``gcs_pdm.models.lanes`` (samples in lanes, the lane index innermost):

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

from dataclasses import dataclass, replace

import numpy as np

from gcs_pdm.models import kernel
from gcs_pdm.models.kernel import N_EXT_PARAMS, N_EXT_STATE, N_MOTOR_PARAMS, N_PACK_PARAMS, N_PACK_STATE, PowertrainRun, _rows
from gcs_pdm.models.lanes import LANES, _simulate  # noqa: F401 (LANES: the driver's block size, re-exported)


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
    tm0 = np.broadcast_to(np.asarray(motor_temp0, dtype=np.float64), (n_vec, n_motors))
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
    own = kernel.owned  # one compiled version of the driver: every array writable and C-contiguous
    _simulate(own(pp), own(ep), own(is_ext, np.bool_), own(mp), own(x0), own(tm0), own(dt_), own(sp), own(f),
              own(amb), own(topo.bus_of_pack, np.int64), own(topo.bus_of_motor, np.int64),
              own(topo.bus_parallel, np.bool_), own(topo.pack_cutoff_v), own(topo.pack_max_temp_c),
              own(topo.motor_max_temp_c), float(fault_drag), float(max_dt), bool(stop_on_failure), slot_of_step,
              *rec, *out.values())
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
