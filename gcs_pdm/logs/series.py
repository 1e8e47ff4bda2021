"""What an autopilot's own log says about the powertrain, as time series; and from them the
fitter's flight tables and the telemetry frames replay and live share.

Both log readers (:mod:`gcs_pdm.logs.dataflash` for ArduPilot, :mod:`gcs_pdm.logs.ulog` for PX4)
fill a :class:`LogSeries`. Times are seconds from the log's first timed message. A value the log
does not have is NaN in the arrays (``None`` in frames), never 0: ArduPilot writes BAT.Temp = 0
when the monitor has no sensor, PX4 writes NaN.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcs_pdm.logs.tables import BATTERY, MOTOR, Flight, FlightDataError, flight_from_columns
from gcs_pdm.models.params import PACK_NAMES


@dataclass
class BatterySeries:
    instance: int
    time_s: np.ndarray
    voltage_v: np.ndarray
    current_a: np.ndarray
    temperature_c: np.ndarray  # NaN where not measured
    consumed_mah: np.ndarray
    cells: int | None = None


@dataclass
class EscSeries:
    instance: int
    time_s: np.ndarray
    rpm: np.ndarray
    current_a: np.ndarray
    temperature_c: np.ndarray


@dataclass
class LogSeries:
    path: Path
    autopilot: str
    batteries: dict[int, BatterySeries] = field(default_factory=dict)
    escs: dict[int, EscSeries] = field(default_factory=dict)
    ambient: tuple[np.ndarray, np.ndarray] | None = None  # (time_s, temperature_c)
    position: dict[str, np.ndarray] | None = None  # time_s, lat_deg, lon_deg, alt_m, vn, ve, vd
    airspeed: tuple[np.ndarray, np.ndarray] | None = None  # (time_s, m/s)
    #: the autopilot's wind estimate: (time_s, north m/s, east m/s), the air's velocity (blowing towards)
    wind: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    modes: list[tuple[float, str]] = field(default_factory=list)
    commands: list[tuple[float, int, int]] = field(default_factory=list)  # items started: (time, seq, MAV_CMD)
    mission: list[tuple[float, int, int]] = field(default_factory=list)  # the stored mission as logged
    texts: list[tuple[float, str]] = field(default_factory=list)
    missing: dict[str, str] = field(default_factory=dict)  # what a model may need that the log lacks, and why
    parameters: dict[str, float] = field(default_factory=dict)  # the autopilot's parameters as logged (last value)
    firmware: str | None = None  # the firmware's name and version as the log gives it
    build: int | None = None  # ArduPilot's VER.BU (APM_BUILD_*: 1 Rover, 2 Copter, 3 Plane, ...)

    def pack_name(self, instance: int) -> str:
        """The project's pack name for a battery instance (instance i is BATTERY_STATUS id i, as in tlogs)."""
        return PACK_NAMES[instance] if instance < len(PACK_NAMES) else f"battery{instance}"

    def packs(self) -> dict[str, BatterySeries]:
        return {self.pack_name(i): b for i, b in sorted(self.batteries.items())}


def _interp(t: np.ndarray, ts: np.ndarray, xs: np.ndarray) -> np.ndarray:
    ok = np.isfinite(ts) & np.isfinite(xs)
    if not ok.any():
        return np.full(t.shape, np.nan)
    return np.interp(t, ts[ok], xs[ok])


def battery_flights(series: LogSeries, pack: str = "all") -> list[Flight]:
    """One battery flight per pack in the log (or the one named): the fitter's table."""
    packs = series.packs()
    if not packs:
        raise FlightDataError(f"{series.path}: no battery messages in the {series.autopilot} log")
    if pack != "all":
        if pack not in packs:
            raise FlightDataError(f"{series.path}: no battery {pack!r} in the log; it has {', '.join(packs)}")
        packs = {pack: packs[pack]}
    out = []
    for name, b in packs.items():
        ambient = _interp(b.time_s, *series.ambient) if series.ambient else np.full(b.time_s.shape, np.nan)
        source = {"file": str(series.path), "pack": name, "instance": b.instance, "autopilot": series.autopilot}
        if series.missing:
            source["missing"] = dict(series.missing)
        out.append(flight_from_columns(f"{series.path.stem}_{name}", BATTERY, {
            "time_s": b.time_s, "current_a": b.current_a, "voltage_v": b.voltage_v,
            "temperature_c": b.temperature_c, "ambient_c": ambient}, source=source))
    return out


def motor_flight(series: LogSeries) -> Flight:
    """The motors' flight: mean current and mean temperature of the ESCs that turned."""
    active = {i: e for i, e in series.escs.items() if np.nanmax(np.abs(e.rpm), initial=0.0) > 0
              or np.nanmax(np.abs(e.current_a), initial=0.0) > 0}
    if not active:
        raise FlightDataError(f"{series.path}: no ESC telemetry with a turning motor in the {series.autopilot} log")
    t = max(active.values(), key=lambda e: e.time_s.size).time_s
    cur = np.nanmean([_interp(t, e.time_s, e.current_a) for e in active.values()], axis=0)
    temps = np.array([_interp(t, e.time_s, e.temperature_c) for e in active.values()])
    with warnings.catch_warnings():  # a time with no temperature from any ESC stays missing
        warnings.simplefilter("ignore", RuntimeWarning)
        temp = np.nanmean(temps, axis=0)
    ambient = _interp(t, *series.ambient) if series.ambient else np.full(t.shape, np.nan)
    return flight_from_columns(f"{series.path.stem}_motor", MOTOR, {
        "time_s": t, "current_a": cur, "temperature_c": temp, "ambient_c": ambient},
        source={"file": str(series.path), "escs": sorted(active), "autopilot": series.autopilot})


def _opt(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def frames(series: LogSeries, pack_names: dict[int, str] | None = None,
           motor_names: dict[int, str] | None = None) -> list:
    """The log as the telemetry frames live MAVLink produces, in time order (``gcs_pdm.frames``).

    ``pack_names`` / ``motor_names`` name the frames of each battery / ESC instance (a vehicle
    description's packs and motors, :func:`described_names`); an instance they leave out gives no
    frames. Without them, battery instance i is the paper's pack i and ESC instance i is ``esc<i>``."""
    from gcs_pdm.frames import (AirdataFrame, AmbientFrame, MissionProgressFrame, MotorFrame, PackFrame,
                                PositionFrame, StatusTextFrame, WindFrame)
    from gcs_pdm.models.wind import speed_direction

    if pack_names is None:
        pack_names = {i: series.pack_name(i) for i in series.batteries}
    if motor_names is None:
        motor_names = {i: f"esc{i}" for i in series.escs}
    out: list = []
    for inst, b in sorted(series.batteries.items()):
        if inst not in pack_names:
            continue
        name = pack_names[inst]
        out += [PackFrame(float(t), name, _opt(v), _opt(i), _opt(c))
                for t, v, i, c in zip(b.time_s, b.voltage_v, b.current_a, b.temperature_c)]
    for inst, e in sorted(series.escs.items()):
        if inst not in motor_names:
            continue
        name = motor_names[inst]
        out += [MotorFrame(float(t), name, _opt(i), _opt(r), _opt(c))
                for t, i, r, c in zip(e.time_s, e.current_a, e.rpm, e.temperature_c)]
    if series.ambient:
        out += [AmbientFrame(float(t), _opt(c)) for t, c in zip(*series.ambient)]
    if series.position:
        p = series.position
        out += [PositionFrame(float(t), _opt(a), _opt(o), _opt(h), None, _opt(n), _opt(e), _opt(d))
                for t, a, o, h, n, e, d in zip(p["time_s"], p["lat_deg"], p["lon_deg"], p["alt_m"], p["vn"],
                                               p["ve"], p["vd"])]
    if series.airspeed:
        out += [AirdataFrame(float(t), _opt(a), None, None, None, None) for t, a in zip(*series.airspeed)]
    if series.wind:
        for t, n, e in zip(*series.wind):
            if np.isfinite(n) and np.isfinite(e):
                speed, from_deg = speed_direction(float(e), float(n))
                out.append(WindFrame(float(t), speed, from_deg))
    out += [MissionProgressFrame(float(t), seq, None) for t, seq, _cmd in series.commands]
    out += [StatusTextFrame(float(t), 6, text) for t, text in series.texts]  # MSG carries no severity
    out.sort(key=lambda f: f.time_s)
    return out


def described_names(series: LogSeries, vehicle) -> tuple[dict[int, str], dict[int, str], dict[str, str]]:
    """A vehicle description's packs and motors by the log's instances: (pack name by battery
    instance, motor name by ESC instance, what the log has that the description does not name and
    why it is left out). A pack is its ``dataflash_instance`` (default: its MAVLink battery id, which
    is the instance ArduPilot and PX4 stream as BATTERY_STATUS.id); a motor is its ESC index."""
    packs = {(p.dataflash_instance if p.dataflash_instance is not None else p.mavlink_battery_id): p.name
             for p in vehicle.packs}
    motors = {m.esc_index: m.name for m in vehicle.motors}
    unnamed = {f"battery instance {i}": f"{series.batteries[i].time_s.size} samples; the description "
               f"{vehicle.name} names no pack for it (its packs are instances {sorted(packs)})"
               for i in sorted(series.batteries) if i not in packs}
    unnamed.update({f"ESC instance {i}": f"{series.escs[i].time_s.size} samples; the description "
                    f"{vehicle.name} names no motor for it (its motors are ESC indices {sorted(motors)})"
                    for i in sorted(series.escs) if i not in motors})
    return packs, motors, unnamed
