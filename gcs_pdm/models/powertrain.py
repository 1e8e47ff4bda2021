"""Flight demand → shaft power → motor and pack currents, for the aircraft of the paper's §III.

The airframe is a 33 %-scale Edge 540-class aerobatic monoplane (the NASA Langley test vehicle's
class). Level-flight power uses the parabolic drag polar; a climb adds m·g·ḣ; a descent gives
back part of it down to a windmilling floor. Propulsive efficiency turns air power into shaft
power. The electrical side (two motors on one shaft, each fed by two packs in series, motor
faults) lives in the kernel (``gcs_pdm.models.topology.simulate_powertrain``) because the current
depends on the packs' voltage at every step. See docs/model.md for the numbers and their sources.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES, ParameterSet

G = 9.80665
SEA_LEVEL_DENSITY = 1.225  # kg/m^3
SEA_LEVEL_TEMP_C = 15.0
LAPSE_RATE = 0.0065  # K/m, ISA troposphere


@dataclass(frozen=True)
class Airframe:
    mass_kg: float = 15.0
    wing_area_m2: float = 1.30
    aspect_ratio: float = 5.2
    cd0: float = 0.040
    oswald: float = 0.80
    #: propeller efficiency (air power / shaft power) in cruise
    eta_prop: float = 0.72
    #: fraction of the climb power a descent gives back before the motors idle
    descent_recovery: float = 0.6
    #: shaft power that never goes away while flying (windmilling floor), W
    min_shaft_power_w: float = 40.0
    prop_diameter_m: float = 0.56  # 22 in
    prop_power_coeff: float = 0.045  # C_P in P = C_P rho n^3 D^5
    cruise_airspeed: float = 25.0
    stall_airspeed: float = 14.0
    max_airspeed: float = 40.0
    max_climb_rate: float = 6.0


EDGE_540 = Airframe()


def air_density(altitude_m: np.ndarray | float, ground_temp_c: float = SEA_LEVEL_TEMP_C) -> np.ndarray:
    """ISA-like density at altitude above sea level (troposphere)."""
    alt = np.asarray(altitude_m, dtype=np.float64)
    t_sl = ground_temp_c + 273.15
    ratio = np.clip(1.0 - LAPSE_RATE * alt / t_sl, 0.2, 1.2)
    return SEA_LEVEL_DENSITY * (288.15 / t_sl) * ratio ** 4.2559


def ambient_temperature(altitude_m: np.ndarray | float, ground_temp_c: float, ground_alt_m: float = 0.0) -> np.ndarray:
    """Ambient air temperature at altitude from a ground value and the standard lapse rate."""
    return ground_temp_c - LAPSE_RATE * (np.asarray(altitude_m, dtype=np.float64) - ground_alt_m)


def shaft_power(airspeed: np.ndarray | float, climb_rate: np.ndarray | float = 0.0,
                density: np.ndarray | float = SEA_LEVEL_DENSITY, airframe: Airframe = EDGE_540) -> np.ndarray:
    """Shaft power (W) the propeller needs for steady flight at an airspeed and climb rate."""
    v = np.maximum(np.asarray(airspeed, dtype=np.float64), 1.0)
    climb = np.asarray(climb_rate, dtype=np.float64)
    rho = np.asarray(density, dtype=np.float64)
    a = airframe
    q = 0.5 * rho * v * v
    weight = a.mass_kg * G
    cl = weight / (q * a.wing_area_m2)
    cd = a.cd0 + cl * cl / (np.pi * a.oswald * a.aspect_ratio)
    drag_power = q * a.wing_area_m2 * cd * v
    climb_power = weight * climb
    climb_power = np.where(climb_power < 0.0, climb_power * a.descent_recovery, climb_power)
    return np.maximum((drag_power + climb_power) / a.eta_prop, a.min_shaft_power_w)


def shaft_rpm(shaft_power_w: np.ndarray | float, density: np.ndarray | float = SEA_LEVEL_DENSITY,
              airframe: Airframe = EDGE_540) -> np.ndarray:
    """Propeller speed (rpm) absorbing a shaft power: P = C_P rho n^3 D^5."""
    p = np.maximum(np.asarray(shaft_power_w, dtype=np.float64), 0.0)
    n = np.cbrt(p / (airframe.prop_power_coeff * np.asarray(density) * airframe.prop_diameter_m ** 5))
    return 60.0 * n


@dataclass(frozen=True)
class MotorFault:
    """Power loss of one motor: it delivers (1 - magnitude) of its share; its rotor still spins."""

    motor: str
    magnitude: float
    kind: str = "motor_power_loss"

    def __post_init__(self) -> None:
        if self.motor not in MOTOR_NAMES and not (type(self) is not MotorFault and isinstance(self.motor, str)
                                                  and self.motor):
            raise ValueError(f"motor: expected one of {MOTOR_NAMES}, got {self.motor!r}")
        if not 0.0 <= float(self.magnitude) <= 1.0:
            raise ValueError(f"magnitude: must be within [0, 1], got {self.magnitude!r}")


@dataclass(frozen=True)
class DescribedMotorFault(MotorFault):
    """A power loss of a vehicle description's motor (any name it gives, e.g. "m2"): flown by the
    description's simulator, never by the paper's four-pack kernel (``fault_vector`` refuses it)."""


def fault_vector(faults: "list[MotorFault] | tuple[MotorFault, ...]" = (),
                 motor_names: "tuple[str, ...] | list[str] | None" = None) -> np.ndarray:
    """Per-motor fault magnitudes for the kernel, in ``motor_names``' order (a vehicle
    description's motors; default the paper's fwd, aft); several faults on one motor compound. A
    fault on a motor the vehicle does not have is an error naming it, never silently dropped."""
    names = list(MOTOR_NAMES if motor_names is None else motor_names)
    health = np.ones(len(names))
    for f in faults:
        if f.motor not in names:
            raise ValueError(f"motor fault: no motor {f.motor!r} on this vehicle; have {', '.join(names)}")
        health[names.index(f.motor)] *= 1.0 - float(f.magnitude)
    return 1.0 - health


@dataclass(frozen=True)
class Limits:
    """Where the vehicle fails: pack terminal voltage floor and temperature ceilings."""

    pack_cutoff_v: float = 17.5  # 3.5 V/cell under load
    pack_max_temp_c: float = 60.0
    motor_max_temp_c: float = 100.0

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.pack_cutoff_v, self.pack_max_temp_c, self.motor_max_temp_c)


@dataclass(frozen=True)
class PowertrainState:
    """Electrical and thermal state of the whole powertrain, as the kernel carries it."""

    pack_state: np.ndarray  # (4, 4) PACK_STATE per pack, PACK_NAMES order
    motor_temp_c: np.ndarray = field(default_factory=lambda: np.full(2, 20.0))  # (2,) fwd, aft

    @classmethod
    def full(cls, params: ParameterSet, temp_c: float = 20.0, soc: float | np.ndarray = 1.0) -> "PowertrainState":
        x = kernel.initial_pack_state(params.pack_matrix(), soc, temp_c)
        return cls(pack_state=x, motor_temp_c=np.full(2, float(temp_c)))

    def soc(self, params: ParameterSet) -> np.ndarray:
        return kernel.state_of_charge(params.pack_matrix(), self.pack_state)

    def pack_voltage(self, params: ParameterSet) -> np.ndarray:
        return kernel.terminal_voltage(params.pack_matrix(), self.pack_state)


def fly(params: ParameterSet, state: PowertrainState, dt: np.ndarray, shaft_power_w: np.ndarray,
        ambient_c: np.ndarray | float, faults: "list[MotorFault] | tuple[MotorFault, ...]" = (),
        limits: Limits | None = None, record: bool = True, stop_on_failure: bool = True,
        **kw) -> kernel.PowertrainRun:
    """One vehicle through a shaft-power profile (a convenience over the batched kernel); it stops
    at the first failure, as the aircraft would."""
    return topology.simulate_powertrain(
        params.pack_matrix()[None], params.motor_vector()[None], state.pack_state[None],
        np.asarray(state.motor_temp_c)[None], dt, shaft_power_w, ambient_c, fault_vector(faults)[None],
        limits=(limits or Limits()).as_tuple(), record=record, stop_on_failure=stop_on_failure, **kw)


__all__ = [
    "Airframe", "EDGE_540", "Limits", "MotorFault", "PowertrainState", "PACK_NAMES", "MOTOR_NAMES",
    "air_density", "ambient_temperature", "fault_vector", "fly", "shaft_power", "shaft_rpm",
]
