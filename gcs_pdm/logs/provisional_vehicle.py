"""A provisional vehicle description from an autopilot's own log (ArduPilot DataFlash ``.bin``,
PX4 ULog ``.ulg``), by the one derivation that serves tlogs and live telemetry.

``log_observations(series)`` turns a :class:`gcs_pdm.logs.series.LogSeries` (read by
``gcs_pdm.logs.reader.read_log``) into the MAVLink messages ``ProvisionalObserver.observe`` folds,
in MAVLink's units: a HEARTBEAT whose type the log names, PARAM_VALUE for the log's parameters,
one BATTERY_STATUS per battery sample (id = the battery instance, as the autopilot streams it)
and one ESC_TELEMETRY_* per ESC sample. A value the log lacks is sent as MAVLink's "unknown"
(temperature INT16_MAX, remaining -1) or 0 for ESC readings (the observer's "no data").

The airframe comes from what the log says (``airframe_of_log``): ArduPilot's VER (build: plane,
copter, rover...) or firmware banner in MSG, with Q_ENABLE (quadplane) and FRAME_CLASS (copter
rotors) from PARM; PX4's MAV_TYPE parameter. A log that names none is assumed a fixed wing, and
the notes say so.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from gcs_pdm.vehicle.description import VehicleDescription, VehicleError
from gcs_pdm.vehicle.provisional import MAV_TYPE_FIXED_WING, ProvisionalObserver

#: ArduPilot's VER.BU (APM_BUILD_*) -> (vehicle, MAV_TYPE; None: decided by FRAME_CLASS / not an aircraft)
_AP_BUILDS = {1: ("Rover", 10), 2: ("ArduCopter", None), 3: ("ArduPlane", MAV_TYPE_FIXED_WING),
              4: ("AntennaTracker", 5), 7: ("ArduSub", 12), 12: ("Blimp", 7)}
#: ArduCopter FRAME_CLASS -> MAV_TYPE (quad, hexa, octa, octaquad, y6, tri, ...)
_AP_FRAME_CLASS = {1: 2, 2: 13, 3: 14, 4: 14, 5: 13, 7: 15, 10: 2, 12: 13, 14: 2}
#: MAV_TYPE of an ArduPlane with Q_ENABLE (a quadplane is a VTOL: MAV_TYPE_VTOL_FIXEDROTOR)
_QUADPLANE = 22
_MAV_AUTOPILOT = {"ArduPilot": 3, "PX4": 12}
_INT16_MAX = 32767
_UINT16_MAX = 65535


def airframe_of_log(series) -> tuple[int, str]:
    """(MAV_TYPE, where it came from — or that it is assumed) for a LogSeries."""
    params = series.parameters
    if series.autopilot == "PX4":
        t = params.get("MAV_TYPE")
        if t is not None and math.isfinite(t):
            return int(t), f"the log's MAV_TYPE parameter ({int(t)})"
    else:
        build = series.firmware or ""
        # the firmware (ArduPlane, ArduCopter, ...): a vehicle *type*, not a description
        firmware_kind, mav_type = next(((v, m) for b, (v, m) in _AP_BUILDS.items() if series.build == b),
                                       (None, None))
        if firmware_kind is None:  # no VER: the firmware banner (MSG) names the vehicle
            firmware_kind, mav_type = next(((v, m) for v, m in _AP_BUILDS.values() if v in build), (None, None))
        if firmware_kind == "ArduPlane":
            if params.get("Q_ENABLE", 0) > 0:
                return _QUADPLANE, f"the log's firmware ({build or firmware_kind}) with Q_ENABLE = 1 (a quadplane)"
            return MAV_TYPE_FIXED_WING, f"the log's firmware ({build or firmware_kind}; Q_ENABLE off)"
        if firmware_kind == "ArduCopter":
            fc = params.get("FRAME_CLASS")
            if fc is not None and int(fc) in _AP_FRAME_CLASS:
                return _AP_FRAME_CLASS[int(fc)], f"the log's firmware ({build or firmware_kind}) and FRAME_CLASS {int(fc)}"
            raise VehicleError(f"{series.path}: an ArduCopter log whose FRAME_CLASS "
                               f"({'absent' if fc is None else int(fc)}) does not say the rotor count: "
                               f"write the description by hand (docs/vehicles.md)")
        if firmware_kind is not None:
            return mav_type, f"the log's firmware ({build or firmware_kind})"
    return MAV_TYPE_FIXED_WING, "nothing in the log (no VER, firmware banner or MAV_TYPE): a fixed wing is ASSUMED"


def _fin(v, scale: float, unknown: int) -> int:
    return int(round(float(v) * scale)) if np.isfinite(v) else unknown


def _voltages(volt: float) -> list[int]:
    """A pack voltage as BATTERY_STATUS.voltages (mV, each entry < 65535: a high-voltage pack spans
    several entries, as ArduPilot sends it), padded with 'not reported'."""
    mv = int(round(volt * 1000.0)) if np.isfinite(volt) and volt > 0 else 0
    out = []
    while mv > 0 and len(out) < 10:
        out.append(min(mv, _UINT16_MAX - 1))
        mv -= out[-1]
    return out + [_UINT16_MAX] * (10 - len(out))


def log_observations(series) -> Iterable[tuple[str, dict]]:
    """The LogSeries as the (message name, fields) pairs ``ProvisionalObserver.observe`` takes."""
    mav_type, _ = airframe_of_log(series)
    yield "HEARTBEAT", {"type": mav_type, "autopilot": _MAV_AUTOPILOT.get(series.autopilot, 0)}
    for name, value in series.parameters.items():
        yield "PARAM_VALUE", {"param_id": name, "param_value": value}
    for inst, b in sorted(series.batteries.items()):
        for v, i, c, mah in zip(b.voltage_v, b.current_a, b.temperature_c, b.consumed_mah):
            yield "BATTERY_STATUS", {"id": inst, "voltages": _voltages(v), "current_battery": _fin(i, 100.0, -1),
                                     "current_consumed": _fin(mah, 1.0, -1), "battery_remaining": -1,
                                     "temperature": _fin(c, 100.0, _INT16_MAX)}
    for inst, e in sorted(series.escs.items()):
        group, k = divmod(inst, 4)
        if group > 3:
            continue  # MAVLink's ESC telemetry stops at 16
        name = f"ESC_TELEMETRY_{4 * group + 1}_TO_{4 * group + 4}"
        for r, i, c in zip(e.rpm, e.current_a, e.temperature_c):
            fields = {key: [0] * 4 for key in ("current", "rpm", "temperature", "voltage", "count")}
            fields["current"][k] = _fin(abs(i), 100.0, 0)
            fields["rpm"][k] = _fin(abs(r), 1.0, 0)
            fields["temperature"][k] = _fin(c, 1.0, 0)
            yield name, fields


def observe_log(path: str | Path, name: str | None = None, capacities: Mapping[int, float] | None = None,
                ) -> tuple[VehicleDescription, list[str]]:
    """The provisional description of the vehicle that wrote ``path`` (``.bin`` or ``.ulg``);
    ``capacities`` (mAh by battery id) for packs whose capacity the log does not give."""
    from gcs_pdm.logs.tables import FlightDataError
    from gcs_pdm.logs.reader import read_log

    try:
        series = read_log(path)
    except (FlightDataError, OSError) as exc:
        raise VehicleError(str(exc)) from None
    obs = ProvisionalObserver()
    obs.airframe_source = airframe_of_log(series)[1]
    for msg_name, fields in log_observations(series):
        obs.observe(msg_name, fields)
    return obs.derive(name or f"provisional-{Path(path).stem}", capacities)


def observe_file(path: str | Path, name: str | None = None, capacities: Mapping[int, float] | None = None,
                 ) -> tuple[VehicleDescription, list[str]]:
    """A tlog, DataFlash or ULog file, by its extension."""
    from gcs_pdm.logs.reader import LOG_SUFFIXES
    from gcs_pdm.mavlink.provisional_vehicle import observe_tlog

    if Path(path).suffix.lower() in LOG_SUFFIXES:
        return observe_log(path, name, capacities)
    return observe_tlog(path, name, capacities)
