"""PX4 ULog ``.ulg`` files through pyulog, into :class:`~gcs_pdm.logs.series.LogSeries`.

Topics read: ``battery_status`` (one per battery instance; ``temperature`` NaN when the monitor
has none, ``cell_count``), ``esc_status`` (``esc[i].esc_rpm``/``esc_current``/``esc_temperature``),
``vehicle_air_data`` (``baro_temp_celcius``: the ambient stand-in, as SCALED_PRESSURE in tlogs),
``vehicle_gps_position`` (``lat``/``lon`` in 1e-7 degrees, or ``latitude_deg`` in newer PX4),
``airspeed``, the EKF's wind (``wind``, or ``wind_estimate`` before PX4 1.13: ``windspeed_north``/``_east``)
and the logged text messages. Timestamps are µs since boot; times here count from
the first sample of these topics.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from gcs_pdm.logs.tables import FlightDataError

TOPICS = ["battery_status", "esc_status", "vehicle_air_data", "vehicle_gps_position", "airspeed",
          "wind", "wind_estimate"]  # the wind topic was wind_estimate before PX4 1.13


def _f(data: dict, name: str, n: int) -> np.ndarray:
    return data[name].astype(np.float64) if name in data else np.full(n, np.nan)


def series_from_ulog(path: str | Path):
    try:
        from pyulog import ULog
    except ImportError:  # pragma: no cover - pyulog is a dependency (docs/dependencies.md)
        raise FlightDataError(f"{path}: reading PX4 ULog files needs the pyulog package") from None
    from gcs_pdm.logs.series import BatterySeries, EscSeries, LogSeries

    path = Path(path)
    if not path.is_file():
        raise FlightDataError(f"{path}: no such file")
    try:
        ulog = ULog(str(path), TOPICS)
    except Exception as exc:  # pyulog raises many kinds for a damaged or foreign file
        raise FlightDataError(f"{path}: not a readable ULog ({type(exc).__name__}: {exc})") from None
    topics = [d for d in ulog.data_list if len(d.data["timestamp"])]
    if not topics:
        raise FlightDataError(f"{path}: none of {', '.join(TOPICS)} in the log")
    # times count from the powertrain and position topics (the wind, read since, must not move them)
    timed = [d for d in topics if d.name not in ("wind", "wind_estimate")] or topics
    t0 = min(int(d.data["timestamp"][0]) for d in timed)
    out = LogSeries(path, "PX4")

    def seconds(d) -> np.ndarray:
        return (d.data["timestamp"].astype(np.int64) - t0) / 1e6

    for d in topics:
        data, n = d.data, len(d.data["timestamp"])
        if d.name == "battery_status":
            cells = data.get("cell_count")
            out.batteries[d.multi_id] = BatterySeries(
                d.multi_id, seconds(d), _f(data, "voltage_v", n), _f(data, "current_a", n),
                _f(data, "temperature", n), _f(data, "discharged_mah", n),
                cells=int(cells[-1]) if cells is not None and cells[-1] > 0 else None)
            if np.isnan(out.batteries[d.multi_id].temperature_c).all():
                out.missing[f"battery{d.multi_id}.temperature_c"] = "battery_status.temperature is NaN throughout"
        elif d.name == "esc_status":
            i = 0
            while f"esc[{i}].esc_rpm" in data:
                temp = _f(data, f"esc[{i}].esc_temperature", n)
                out.escs[i] = EscSeries(i, seconds(d), _f(data, f"esc[{i}].esc_rpm", n),
                                        _f(data, f"esc[{i}].esc_current", n), np.where(temp == 0, np.nan, temp))
                i += 1
        elif d.name == "vehicle_air_data" and d.multi_id == 0:
            out.ambient = (seconds(d), _f(data, "baro_temp_celcius", n))
        elif d.name == "vehicle_gps_position" and d.multi_id == 0:
            lat = data["lat"] * 1e-7 if "lat" in data else _f(data, "latitude_deg", n)
            lon = data["lon"] * 1e-7 if "lon" in data else _f(data, "longitude_deg", n)
            alt = data["alt"] * 1e-3 if "alt" in data else _f(data, "altitude_msl_m", n)
            out.position = {"time_s": seconds(d), "lat_deg": lat, "lon_deg": lon, "alt_m": alt,
                            "vn": _f(data, "vel_n_m_s", n), "ve": _f(data, "vel_e_m_s", n),
                            "vd": _f(data, "vel_d_m_s", n)}
        elif d.name == "airspeed" and d.multi_id == 0:
            out.airspeed = (seconds(d), _f(data, "true_airspeed_m_s", n))
        elif d.name in ("wind", "wind_estimate") and d.multi_id == 0 and out.wind is None:
            out.wind = (seconds(d), _f(data, "windspeed_north", n), _f(data, "windspeed_east", n))
    if out.ambient is None:
        out.missing["ambient_c"] = "no vehicle_air_data topic"
    out.texts = [((m.timestamp - t0) / 1e6, m.message) for m in ulog.logged_messages]
    # initial values, then each change in flight in time order: the last value wins
    out.parameters = {str(k): float(v) for k, v in ulog.initial_parameters.items()}
    out.parameters.update({str(k): float(v) for _t, k, v in ulog.changed_parameters})
    info = ulog.msg_info_dict
    out.firmware = " ".join(str(info[k]) for k in ("sys_name", "ver_sw") if k in info) or None
    return out
