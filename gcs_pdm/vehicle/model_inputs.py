"""Description -> the model's inputs: parameter vectors per pack and motor, and the topology.

Packs and motors come in the description's order. The topology is given per bus (a set of packs
joined in series or in parallel driving some motors): ``bus_of_pack``, ``bus_of_motor`` and
``bus_parallel``. For ``edge540`` this is exactly what the code always used: the ``paper_si``
pack matrix and ``kernel.STRING_OF_PACK`` (tests/test_vehicle_description.py holds it).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from gcs_pdm.models.training_envelope import training_envelopes
from gcs_pdm.models.pack_scaling import scale_pack_vector
from gcs_pdm.models.params import (BUILTIN_SETS, CELLS_PER_PACK, PACK_CAPACITY_C, ParameterError, ParameterSet,
                                   motor_vector, pack_vector)
from gcs_pdm.vehicle.description import PackSpec, VehicleDescription, VehicleError

#: the chemistry default: the paper_si set's first pack (a 5S 7.8 Ah LiPo), scaled to each pack
CHEMISTRY_DEFAULT_SOURCE = ("paper_si", "LLF20")


@dataclass(frozen=True)
class ModelInputs:
    pack_names: tuple[str, ...]
    motor_names: tuple[str, ...]
    pack_matrix: np.ndarray      # (N, 12) kernel.PACK_PARAMS order
    motor_matrix: np.ndarray     # (M, 5) kernel.MOTOR_PARAMS order
    bus_of_pack: np.ndarray      # (N,) int
    bus_of_motor: np.ndarray     # (M,) int
    bus_parallel: np.ndarray     # (B,) bool: packs of the bus in parallel (else in series)
    pack_cutoff_v: np.ndarray    # (N,) terminal voltage floor, V
    pack_max_temp_c: np.ndarray  # (N,)
    motor_max_temp_c: np.ndarray  # (M,)
    #: per pack index: its extended-variant values (``PackParams.extended_vector``) where a parameter
    #: set flown over the description holds the pack on the extended model (docs/model.md)
    extended_packs: dict = field(default_factory=dict)
    #: a parameter set's values were flown over the description's (``model_inputs(desc, params)``)
    from_parameter_set: bool = False

    @property
    def n_packs(self) -> int:
        return len(self.pack_names)

    @property
    def n_motors(self) -> int:
        return len(self.motor_names)

    @property
    def topology(self):
        from gcs_pdm.models.topology import Topology

        return Topology(self.bus_of_pack, self.bus_of_motor, self.bus_parallel, self.pack_cutoff_v,
                        self.pack_max_temp_c, self.motor_max_temp_c)

    def packs_of_motor(self, q: int) -> tuple[int, ...]:
        return tuple(int(b) for b in np.flatnonzero(self.bus_of_pack == self.bus_of_motor[q]))

    def motors_of_pack(self, b: int) -> tuple[int, ...]:
        return tuple(int(q) for q in np.flatnonzero(self.bus_of_motor == self.bus_of_pack[b]))

    def series_mates(self, b: int) -> tuple[int, ...]:
        """Packs that carry the same current as pack ``b`` (the rest of its series string)."""
        bus = self.bus_of_pack[b]
        if self.bus_parallel[bus]:
            return ()
        return tuple(int(o) for o in np.flatnonzero(self.bus_of_pack == bus) if o != b)


@lru_cache(maxsize=32)
def _parameter_set(ref: str) -> ParameterSet:
    if ref in BUILTIN_SETS:
        return BUILTIN_SETS[ref]
    path = Path(ref)
    try:
        return ParameterSet.from_json(path.read_text())
    except OSError as exc:
        raise VehicleError(f"parameter set {ref!r}: not a built-in set ({', '.join(BUILTIN_SETS)}) "
                           f"and not readable: {exc.strerror or exc}") from None
    except ParameterError as exc:
        raise VehicleError(f"parameter set {ref!r}: {exc}") from None


def _source(spec: PackSpec, where: str) -> tuple[ParameterSet, str, bool]:
    """(set, pack name in it, scaled to this pack?) of a pack's ``parameters`` reference."""
    ref = spec.parameters
    if ref.set == "chemistry-default":
        set_name, pack_name, scale = *CHEMISTRY_DEFAULT_SOURCE, True
    else:
        set_name, pack_name, scale = ref.set, ref.pack, ref.scale_to_pack
    ps = _parameter_set(set_name)
    if pack_name not in ps.packs:
        raise VehicleError(f"{where}.parameters.pack: no pack {pack_name!r} in set {set_name!r}; "
                           f"have {', '.join(ps.packs)}")
    return ps, pack_name, scale


def _source_format(ps: ParameterSet, pack_name: str) -> tuple[int, float]:
    """(cells in series, capacity C) of a set's pack: a vehicle's fitted set (gcs-pdm fit --vehicle)
    says each pack's format; the built-in and paper-layout sets hold the paper's 5S 7.8 Ah packs."""
    fmt = (ps.provenance.get("pack_formats") or {}).get(pack_name)
    return ((int(fmt["cells_series"]), float(fmt["capacity_mah"]) * 3.6) if fmt
            else (CELLS_PER_PACK, PACK_CAPACITY_C))


def pack_parameters(spec: PackSpec, where: str = "pack") -> np.ndarray:
    """One pack's parameter vector (kernel.PACK_PARAMS order) from its ``parameters`` reference."""
    ps, pack_name, scale = _source(spec, where)
    v = pack_vector(ps.packs[pack_name])
    if not scale:
        return v
    ref_cells, ref_capacity = _source_format(ps, pack_name)
    return scale_pack_vector(v, ref_cells, ref_capacity, spec.cells_series, spec.capacity_c, spec.full_cell_v)


def pack_training_envelope(spec: PackSpec, where: str = "pack") -> dict | None:
    """The training envelope of the fit that made the values this pack flies (models.training_envelope), its
    current in this pack's amps when the values are scaled to it; None when no fit made them: a set
    without one, or an extended pack (a description flies a pack's paper values, which an extended
    fit does not learn)."""
    ps, pack_name, scale = _source(spec, where)
    envelope = training_envelopes(ps.provenance).get(pack_name)
    if envelope is None or ps.packs[pack_name].model != "paper":
        return None
    if scale and envelope.get("sustained_current_a") is not None:
        # the same C-rate on this pack's capacity (temperatures are the cells', unscaled)
        envelope["sustained_current_a"] *= spec.capacity_c / _source_format(ps, pack_name)[1]
    return envelope


def model_inputs(desc: VehicleDescription, params: ParameterSet | None = None) -> ModelInputs:
    """The description's packs, motors, buses and limits, with their values from it or, given
    ``params`` (the paper's set, a learned one, a scenario's truth), from that set: each pack's by
    its name (its extended values too where the set holds it extended), every motor the set's one
    motor type. The set overrides values only: the layout and limits stay the description's."""
    inputs = _described_inputs(desc)
    if params is None:
        return inputs
    missing = [n for n in inputs.pack_names if n not in params.packs]
    if missing:
        raise VehicleError(f"parameter set {params.name!r} has no pack {', '.join(missing)} of vehicle "
                           f"{desc.name!r} (its packs: {', '.join(params.packs)})")
    return replace(inputs, pack_matrix=np.stack([pack_vector(params.packs[n]) for n in inputs.pack_names]),
                   motor_matrix=np.tile(params.motor_vector(), (inputs.n_motors, 1)),
                   extended_packs={b: params.packs[n].extended_vector() for b, n in enumerate(inputs.pack_names)
                                   if params.packs[n].model == "extended"},
                   from_parameter_set=True)


def _described_inputs(desc: VehicleDescription) -> ModelInputs:
    packs = np.stack([pack_parameters(p, f"packs[{i}]") for i, p in enumerate(desc.packs)])
    motors = []
    for m in desc.motors:
        if m.values is not None:
            motors.append(np.array([getattr(m.values, k) for k in ("R_w", "I_0", "P_iron", "C_t", "h")]))
        else:
            motors.append(motor_vector(_parameter_set(m.parameter_set).motor))
    return ModelInputs(
        pack_names=desc.pack_names,
        motor_names=desc.motor_names,
        pack_matrix=packs,
        motor_matrix=np.stack(motors),
        bus_of_pack=np.array([desc.bus_of_pack(n) for n in desc.pack_names], dtype=np.int64),
        bus_of_motor=np.array([desc.bus_of_motor(n) for n in desc.motor_names], dtype=np.int64),
        bus_parallel=np.array([b.arrangement == "parallel" for b in desc.buses]),
        pack_cutoff_v=np.array([p.cutoff_voltage for p in desc.packs]),
        pack_max_temp_c=np.array([p.max_temp_c for p in desc.packs]),
        motor_max_temp_c=np.array([m.max_temp_c for m in desc.motors]),
    )


#: MAV_TYPE a multirotor with this many rotors reports in its HEARTBEAT
MAV_TYPE_OF_ROTORS = {2: 3, 3: 15, 4: 2, 6: 13, 8: 14}
MAV_TYPE_FIXED_WING = 1


def mav_type(desc: VehicleDescription) -> int:
    """The HEARTBEAT type such a vehicle sends (the inverse of the provisional derivation's)."""
    if desc.airframe.type == "fixed_wing":
        return MAV_TYPE_FIXED_WING
    try:
        return MAV_TYPE_OF_ROTORS[len(desc.motors)]
    except KeyError:
        raise VehicleError(f"motors: no MAV_TYPE for a multirotor with {len(desc.motors)} rotors") from None


def powertrain_airframe(desc: VehicleDescription):
    """``powertrain.Airframe`` for the description: a fixed wing's drag polar as it is; for a
    multirotor only what the rest reads of it (mass, speeds, the rotor as the propeller for rpm) —
    its power comes from ``models.multirotor``."""
    from gcs_pdm.models.powertrain import Airframe

    af = desc.airframe
    if af.type == "fixed_wing":
        return Airframe(mass_kg=desc.mass_kg, **{k: getattr(af, k) for k in (
            "wing_area_m2", "aspect_ratio", "cd0", "oswald", "eta_prop", "descent_recovery", "min_shaft_power_w",
            "prop_diameter_m", "prop_power_coeff", "stall_airspeed", "max_airspeed")},
            cruise_airspeed=desc.cruise_speed_mps, max_climb_rate=desc.climb_rate_mps)
    return Airframe(mass_kg=desc.mass_kg, prop_diameter_m=af.rotor_diameter_m, stall_airspeed=1.0,
                    max_airspeed=af.max_airspeed, cruise_airspeed=desc.cruise_speed_mps,
                    max_climb_rate=desc.climb_rate_mps)


def shaft_power_model(desc: VehicleDescription):
    """(airspeed m/s, climb m/s, density kg/m³) -> shaft power W, by the airframe's model."""
    from gcs_pdm.models import multirotor, powertrain

    af = desc.airframe
    if af.type == "fixed_wing":
        frame = powertrain_airframe(desc)
        return lambda v, climb, rho: powertrain.shaft_power(v, climb, rho, frame)
    n = len(desc.motors)
    return lambda v, climb, rho: multirotor.shaft_power(v, climb, desc.mass_kg, n, af.rotor_diameter_m,
                                                        af.figure_of_merit, af.drag_area_m2, af.tip_speed_mps, rho)
