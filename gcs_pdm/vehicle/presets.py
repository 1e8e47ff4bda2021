"""Built-in vehicle descriptions (docs/vehicles.md lists them with their sources).

``edge540`` is the paper's aircraft exactly as the rest of gcs-pdm has always assumed it (four 5S
7.8 Ah packs in two series strings, two motors on one shaft at ESC indices 0 and 1, the
``paper_si`` parameter set); its model inputs equal ``default_set().pack_matrix()`` (a test holds
this). The others are typical vehicles whose packs use the chemistry default scaled to the pack.
"""
from __future__ import annotations

from pathlib import Path

from gcs_pdm.models.params import PACK_NAMES, default_set
from gcs_pdm.models.powertrain import EDGE_540, Limits
from gcs_pdm.vehicle.description import VehicleDescription, VehicleError, from_dict, load


def _edge540() -> dict:
    a = EDGE_540
    limits = Limits()
    return {
        "name": "edge540",
        "description": "The paper's 33 %-scale Edge 540: four 5S 7.8 Ah LiPo packs in two series strings, "
                       "two motors on one shaft",
        "packs": [{"name": n, "mavlink_battery_id": i, "cells_series": 5, "capacity_mah": 7800.0,
                   "chemistry": "lipo", "cutoff_v_per_cell": limits.pack_cutoff_v / 5,
                   "max_temp_c": limits.pack_max_temp_c, "self_calibrate": False,  # fitted: flown as set until a flight contradicts it (fitted_prior)
                   "parameters": {"set": default_set().name, "pack": n}} for i, n in enumerate(PACK_NAMES)],
        "motors": [{"name": n, "esc_index": i, "max_temp_c": limits.motor_max_temp_c, "parameter_set": default_set().name}
                   for i, n in enumerate(("fwd", "aft"))],
        "buses": [{"packs": ["LLF20", "LRF40"], "arrangement": "series", "motors": ["fwd"]},
                  {"packs": ["ULA20", "URA40"], "arrangement": "series", "motors": ["aft"]}],
        "airframe": {"type": "fixed_wing", "wing_area_m2": a.wing_area_m2, "aspect_ratio": a.aspect_ratio,
                     "cd0": a.cd0, "oswald": a.oswald, "eta_prop": a.eta_prop,
                     "descent_recovery": a.descent_recovery, "min_shaft_power_w": a.min_shaft_power_w,
                     "prop_diameter_m": a.prop_diameter_m, "prop_power_coeff": a.prop_power_coeff,
                     "stall_airspeed": a.stall_airspeed, "max_airspeed": a.max_airspeed, "shared_shaft": True,
                     "predict_with_drag_polar": True},
        "mass_kg": a.mass_kg,
        "cruise_speed_mps": a.cruise_airspeed,
        "climb_rate_mps": a.max_climb_rate,
        "mission_reward": 100.0,
        "landing_reserve": 0.15,
        "current_references": 1,  # the paper's packs and ESCs read one current: one other reading suffices
    }


#: a 28xx-class out-runner on a 10-15 inch propeller: ~0.1 kg of copper and iron
_SMALL_MOTOR = {"R_w": 0.08, "I_0": 0.6, "P_iron": 3.0, "C_t": 45.0, "h": 0.9}
#: a 40xx-class multirotor motor on an 18 inch propeller
_LARGE_MOTOR = {"R_w": 0.05, "I_0": 0.9, "P_iron": 6.0, "C_t": 90.0, "h": 1.5}


def _plane_3s() -> dict:
    # stock ArduPlane: one battery monitor (BATTERY_STATUS id 0), no pack temperature, the throttle
    # on SERVO3 so its ESC telemetry sits at index 2 (see ../shared/logs/README.md)
    return {
        "name": "plane-3s",
        "description": "A single-battery electric trainer like stock ArduPlane SITL: 3S 3.3 Ah, one motor at ESC index 2",
        # SITL's simulated pack rests at 4.24 V/cell when full and still gives 4.09 V/cell at half
        # charge under cruise current: stiffer and flatter than the chemistry default, whose linear
        # open-circuit curve from 4.2 V/cell would put it above full. 4.35 V/cell keeps SITL's
        # readings inside the model; a pack fitted on its own logs does better (docs/vehicles.md)
        "packs": [{"name": "battery", "mavlink_battery_id": 0, "cells_series": 3, "capacity_mah": 3300.0,
                   "full_cell_voltage": 4.35, "reports_temperature": False}],
        "motors": [{"name": "motor", "esc_index": 2, "values": _SMALL_MOTOR}],
        "buses": [{"packs": ["battery"], "motors": ["motor"]}],
        "airframe": {"type": "fixed_wing", "wing_area_m2": 0.45, "aspect_ratio": 7.0, "cd0": 0.035, "oswald": 0.8,
                     "eta_prop": 0.65, "min_shaft_power_w": 5.0, "prop_diameter_m": 0.28,
                     "stall_airspeed": 10.0, "max_airspeed": 30.0},
        "mass_kg": 2.0,
        "cruise_speed_mps": 20.0,
        "climb_rate_mps": 4.0,
        "landing_reserve": 0.2,
    }


def _multirotor(name: str, text: str, cells: int, capacity_mah: float, n_packs: int, n_motors: int, mass: float,
                rotor_d: float, drag_area: float, motor: dict) -> dict:
    packs = [{"name": f"battery{i + 1}" if n_packs > 1 else "battery", "mavlink_battery_id": i,
              "cells_series": cells, "capacity_mah": capacity_mah} for i in range(n_packs)]
    motors = [{"name": f"m{i + 1}", "esc_index": i, "values": motor} for i in range(n_motors)]
    return {
        "name": name,
        "description": text,
        "packs": packs,
        "motors": motors,
        "buses": [{"packs": [p["name"] for p in packs], "arrangement": "parallel",
                   "motors": [m["name"] for m in motors]}],
        "airframe": {"type": "multirotor", "rotor_diameter_m": rotor_d, "drag_area_m2": drag_area,
                     "max_airspeed": 15.0},
        "mass_kg": mass,
        "cruise_speed_mps": 8.0,
        "climb_rate_mps": 2.5,
        "landing_reserve": 0.25,
    }


def _build() -> dict[str, VehicleDescription]:
    raw = [
        _edge540(),
        _plane_3s(),
        _multirotor("quad-4s", "A 1.6 kg quadcopter on 10 inch propellers, one 4S 5 Ah pack", 4, 5000.0, 1, 4, 1.6,
                    0.254, 0.015, _SMALL_MOTOR),
        _multirotor("quad-6s", "A 4 kg quadcopter on 15 inch propellers, one 6S 10 Ah pack", 6, 10000.0, 1, 4, 4.0,
                    0.381, 0.03, _SMALL_MOTOR),
        _multirotor("hex-6s", "An 8 kg hexacopter on 18 inch propellers, two 6S 10 Ah packs in parallel", 6, 10000.0,
                    2, 6, 8.0, 0.457, 0.05, _LARGE_MOTOR),
    ]
    return {d["name"]: from_dict(d) for d in raw}


PRESETS: dict[str, VehicleDescription] = _build()
DEFAULT_PRESET = "edge540"


def resolve(spec: str | Path | VehicleDescription) -> VehicleDescription:
    """``--vehicle FILE|PRESET``: a preset's name, or a description file."""
    if isinstance(spec, VehicleDescription):
        return spec
    if str(spec) in PRESETS:
        return PRESETS[str(spec)]
    if Path(spec).exists():
        return load(spec)
    raise VehicleError(f"--vehicle {spec}: neither a preset ({', '.join(PRESETS)}) nor a file")


def is_paper_aircraft(desc) -> bool:
    """The ``edge540`` preset: the service and replay run the paper's own code path for it (the
    shared-shaft motor detector, the active parameter set), which it reproduces exactly."""
    return desc == PRESETS[DEFAULT_PRESET]
