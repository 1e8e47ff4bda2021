"""A flight log (tlog, DataFlash ``.bin``, ULog ``.ulg``) read as what the packs need: each battery
slot's current, voltage and temperature, the serial number and rated capacity the autopilot gives
for it, and when the vehicle was armed (shell: file I/O).

* tlog: HEARTBEAT (the vehicle's: not a GCS, not MAV_AUTOPILOT_INVALID) for the armed flag,
  BATTERY_STATUS per battery id (SYS_STATUS as battery 0 when there is none), SMART_BATTERY_INFO
  for serial number, rated capacity and cells in series, PARAM_VALUE ``BATT*_CAPACITY`` (mAh) and
  ``BATT*_SERIAL_NUM`` when the ground station fetched them. Time: the tlog's record stamps.
* ``.bin``/``.ulg``: the battery series of :mod:`gcs_pdm.logs` (the autopilot logs from arming to
  disarm by default, so the log is one flight); serials from ``BATT*_SERIAL_NUM`` (ArduPilot) or
  ``battery_status.serial_number`` (PX4), capacities from ``BATT*_CAPACITY`` / ``BAT*_CAPACITY``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcs_pdm.logs.tables import FlightDataError
from gcs_pdm.packs.identity import serial_text

LOG_KINDS = {".tlog": "tlog", ".bin": "dataflash", ".ulg": "ulog"}
MAV_AUTOPILOT_INVALID, MAV_TYPE_GCS = 8, 6
MAV_MODE_FLAG_SAFETY_ARMED = 128


class PackLogError(FlightDataError):
    """A log that cannot give pack records (reported, and the batch goes on)."""


@dataclass
class SlotSeries:
    slot: str
    time_s: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    temperature_c: np.ndarray
    serial: str | None = None
    rated_capacity_ah: float | None = None
    cells_series: int | None = None


@dataclass
class PackLog:
    path: Path
    kind: str
    slots: list[SlotSeries]
    #: (time_s, armed) samples; None: the log is one flight (an autopilot's own log)
    armed: tuple[np.ndarray, np.ndarray] | None
    #: the log's first time as an absolute (epoch) time where the log gives one, for ordering flights
    epoch_s: float | None = None
    notes: list[str] = field(default_factory=list)


def slot_name(instance: int) -> str:
    return f"battery{int(instance)}"


def read_pack_log(path: str | Path) -> PackLog:
    path = Path(path)
    kind = LOG_KINDS.get(path.suffix.lower())
    if kind is None:
        raise PackLogError(f"{path.name}: not a flight log (expected {', '.join(LOG_KINDS)})")
    if kind == "tlog":
        return _read_tlog(path)
    return _read_autopilot_log(path, kind)


def _param_number(params: dict, names) -> float | None:
    for n in names:
        v = params.get(n)
        if v is not None and np.isfinite(v) and v > 0:
            return float(v)
    return None


def _battery_param_names(instance: int, suffix: str, prefixes=("BATT", "BAT")) -> list[str]:
    k = "" if instance == 0 else str(instance + 1)
    return [f"{p}{k}_{suffix}" for p in prefixes] + ([f"BAT1_{suffix}"] if instance == 0 else [f"BAT{instance + 1}_{suffix}"])


def _read_tlog(path: Path) -> PackLog:
    from gcs_pdm.mavlink.tlog import tlog_message_columns, tlog_message_dicts

    try:
        hb = tlog_message_columns(path, "HEARTBEAT")
    except (OSError, ValueError) as exc:
        raise PackLogError(f"{path.name}: cannot be read as a tlog ({exc})") from None
    vehicle = (hb["autopilot"] != MAV_AUTOPILOT_INVALID) & (hb["type"] != MAV_TYPE_GCS)
    if not vehicle.any():
        raise PackLogError(f"{path.name}: no heartbeat from a vehicle (not a tlog, or a ground station's only)")
    sysids, counts = np.unique(hb["sysid"][vehicle], return_counts=True)
    sysid = int(sysids[np.argmax(counts)])
    mine = vehicle & (hb["sysid"] == sysid)
    t_hb = hb["tlog_time_us"][mine] / 1e6
    t0 = float(t_hb.min())
    armed = (t_hb - t0, (hb["base_mode"][mine].astype(np.int64) & MAV_MODE_FLAG_SAFETY_ARMED) != 0)
    params: dict[str, float] = {}
    smart: dict[int, dict] = {}
    for name, msg in tlog_message_dicts(path, ("PARAM_VALUE", "SMART_BATTERY_INFO"), system=sysid):
        if name == "PARAM_VALUE":
            params[str(msg.get("param_id", "")).strip("\x00")] = float(msg.get("param_value", np.nan))
        else:
            smart[int(msg.get("id", 0))] = msg
    slots = []
    bs = tlog_message_columns(path, "BATTERY_STATUS", system=sysid)
    if bs["id"].size:
        ids = bs["id"].astype(np.int64)
        for inst in np.unique(ids):
            m = ids == inst
            cells = np.concatenate([bs["voltages"][m], bs["voltages_ext"][m]], axis=1).astype(np.float64)
            valid = (cells > 0) & (cells < 65535)
            volts = np.where(valid, cells, 0.0).sum(axis=1) / 1000.0
            volts[~valid.any(axis=1)] = np.nan
            per_cell = valid[:, :10].sum(axis=1)
            cur = bs["current_battery"][m].astype(np.float64)
            cur = np.where(cur == -1, np.nan, cur / 100.0)
            temp = bs["temperature"][m].astype(np.float64)
            temp = np.where(temp == 32767, np.nan, temp / 100.0)
            t = bs["tlog_time_us"][m] / 1e6 - t0
            slots.append(SlotSeries(slot_name(inst), t, cur, volts, temp,
                                    cells_series=int(np.median(per_cell)) if np.median(per_cell) > 1 else None))
    else:
        ss = tlog_message_columns(path, "SYS_STATUS", system=sysid)
        if ss["voltage_battery"].size:
            v = ss["voltage_battery"].astype(np.float64)
            c = ss["current_battery"].astype(np.float64)
            slots.append(SlotSeries(slot_name(0), ss["tlog_time_us"] / 1e6 - t0,
                                    np.where(c == -1, np.nan, c / 100.0), np.where(v == 65535, np.nan, v / 1000.0),
                                    np.full(v.size, np.nan)))
    if not slots:
        raise PackLogError(f"{path.name}: no BATTERY_STATUS or SYS_STATUS from vehicle {sysid}")
    for s in slots:
        inst = int(s.slot[len("battery"):])
        info = smart.get(inst)
        if info is not None:
            s.serial = serial_text(info.get("serial_number"))
            cap = max(float(info.get("capacity_full_specification", -1)), 0.0) or max(float(info.get("capacity_full", -1)), 0.0)
            s.rated_capacity_ah = cap / 1000.0 if cap > 0 else None
            cells = int(info.get("cells_in_series", 0) or 0)
            s.cells_series = cells or s.cells_series
        if s.serial is None:
            sn = _param_number(params, _battery_param_names(inst, "SERIAL_NUM"))
            s.serial = str(int(sn)) if sn is not None else None
        if s.rated_capacity_ah is None:
            mah = _param_number(params, _battery_param_names(inst, "CAPACITY"))
            s.rated_capacity_ah = mah / 1000.0 if mah is not None else None
    return PackLog(path, "tlog", slots, armed, epoch_s=t0)


def _read_autopilot_log(path: Path, kind: str) -> PackLog:
    from gcs_pdm.logs.reader import read_log

    try:
        series = read_log(path)
    except FlightDataError as exc:
        raise PackLogError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - a damaged file: reported, the batch goes on
        raise PackLogError(f"{path.name}: cannot be read ({type(exc).__name__}: {exc})") from None
    if not series.batteries:
        raise PackLogError(f"{path.name}: no battery messages in the log")
    params = series.parameters or {}
    ulog_serials = _ulog_serials(path) if kind == "ulog" else {}
    slots = []
    for inst, b in sorted(series.batteries.items()):
        s = SlotSeries(slot_name(inst), np.asarray(b.time_s, float), np.asarray(b.current_a, float),
                       np.asarray(b.voltage_v, float), np.asarray(b.temperature_c, float), cells_series=b.cells)
        sn = ulog_serials.get(inst) or _param_number(params, _battery_param_names(inst, "SERIAL_NUM"))
        s.serial = str(int(sn)) if sn else None
        mah = _param_number(params, _battery_param_names(inst, "CAPACITY"))
        s.rated_capacity_ah = mah / 1000.0 if mah is not None else None
        slots.append(s)
    return PackLog(path, kind, slots, None, notes=["autopilot log: one flight per log"])


def _ulog_serials(path: Path) -> dict[int, int]:
    """PX4's battery_status.serial_number per instance (0: none), when pyulog can read it."""
    try:
        from pyulog import ULog

        out = {}
        for d in ULog(str(path), ["battery_status"]).data_list:
            sn = d.data.get("serial_number")
            if sn is not None and np.size(sn) and int(np.max(sn)) > 0:
                out[int(d.multi_id)] = int(np.max(sn))
        return out
    except Exception:  # noqa: BLE001 - no serial is a fallback, not a failure
        return {}
