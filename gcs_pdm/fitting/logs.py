"""Reading flight logs (CSV, Parquet, MAVLink tlog, autopilot .bin/.ulg via gcs_pdm.logs) into :class:`~gcs_pdm.logs.tables.Flight` s,
and writing a fit's outputs (``result.json``, ``predictions/<flight>.csv``, plots). Shell module: files.

Tables: one flight per file with the columns of :mod:`gcs_pdm.logs.tables` (extra columns are
ignored). Tlogs go through the MAVLink engineer's scanner and frame mapping (``gcs_pdm.mavlink``),
stamped with the tlog record time (see ``_collect_tlog``): every pack's ``PackFrame`` becomes a battery flight (ambient from
``AmbientFrame``, interpolated to the pack's times), and the ``MotorFrame`` streams become one
motor flight (mean current, mean of the reported temperatures: one bracket sensor).

Logs are read for a vehicle description (the paper's aircraft is the ``edge540`` preset): it names
the packs and says where each is in the log (BATTERY_STATUS id, DataFlash/battery instance). The
command line resolves "no ``--vehicle``" to a description derived from an autopilot log, else to
``edge540``; nothing here guesses one.
"""
from __future__ import annotations

import json
import logging
import re
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gcs_pdm.logs.tables import BATTERY, KINDS, MOTOR, Flight, FlightDataError, flight_from_columns

if TYPE_CHECKING:  # pragma: no cover
    from gcs_pdm.fitting.procedure import FitResult
    from gcs_pdm.vehicle.description import VehicleDescription

log = logging.getLogger(__name__)

TABLE_SUFFIXES = (".csv", ".parquet", ".pq")
TLOG_SUFFIXES = (".tlog",)
AUTOPILOT_LOG_SUFFIXES = (".bin", ".ulg")  # ArduPilot DataFlash, PX4 ULog (gcs_pdm.logs)


def read_table(path: str | Path, kind: str, name: str | None = None) -> Flight:
    """One flight from a CSV or Parquet table."""
    import pandas as pd

    path = Path(path)
    name = name or path.stem
    if not path.is_file():
        raise FlightDataError(f"{path}: no such file")
    try:
        if path.suffix.lower() == ".csv":
            df = pd.read_csv(path)
        elif path.suffix.lower() in (".parquet", ".pq"):
            df = pd.read_parquet(path)
        else:
            raise FlightDataError(f"{path}: unknown table format {path.suffix!r} (use .csv, .parquet or .tlog)")
    except FlightDataError:
        raise
    except Exception as exc:  # pandas/pyarrow raise many types for a damaged file
        raise FlightDataError(f"{path}: cannot read table ({type(exc).__name__}: {exc})") from None
    df.columns = [str(c).strip() for c in df.columns]
    return flight_from_columns(name, kind, df, source={"file": str(path)})


class _FrameCollector:
    """Collects pack, motor and ambient frames from a tlog replay."""

    def __init__(self, packs: tuple[str, ...]) -> None:
        self.packs: dict[str, list[tuple]] = {p: [] for p in packs}
        self.motors: dict[str, list[tuple]] = {}
        self.ambient: list[tuple] = []
        self.battery_status_messages = 0  # all BATTERY_STATUS packets, to explain a pack with no frames

    def __call__(self, frame, t: float) -> None:
        kind = type(frame).__name__
        if kind == "PackFrame" and frame.pack in self.packs:
            self.packs[frame.pack].append((t, _f(frame.current_a), _f(frame.voltage_v), _f(frame.temperature_c)))
        elif kind == "MotorFrame":
            self.motors.setdefault(frame.motor, []).append((t, _f(frame.current_a), _f(frame.temperature_c)))
        elif kind == "AmbientFrame":
            self.ambient.append((t, _f(frame.temperature_c)))


def _f(v) -> float:
    return float("nan") if v is None else float(v)


def _interp(t: np.ndarray, ts: np.ndarray, xs: np.ndarray) -> np.ndarray:
    ok = np.isfinite(ts) & np.isfinite(xs)
    if not ok.any():
        return np.full(t.shape, np.nan)
    order = np.argsort(ts[ok])
    return np.interp(t, ts[ok][order], xs[ok][order])


def _collect_tlog(path: Path, col: "_FrameCollector", mapping: dict) -> None:
    """Feed every packet of a tlog to the MAVLink engineer's frame mapping; stamp each frame with
    its tlog record time.

    Why not the frame's own ``time_s``: the vehicle clock stamps messages without a time field
    (BATTERY_STATUS, ESC telemetry) "hold last" with the latest timed message, a resolution of that
    stream's period (5 s in the simulated vehicle's logs) — 4 of 5 battery samples would share a
    time. The tlog record time has the log's own resolution and is a property of the log, not of
    this process's clock; times count from the log's first record. Frames the mapping held back until the vehicle clock synced arrive
    together; they keep their back-dated spacing.
    """
    from gcs_pdm.mavlink.dialect import MESSAGE_IDS_BY_NAME
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.tlog import ScanStats, scan_tlog_bytes

    battery_status = MESSAGE_IDS_BY_NAME["BATTERY_STATUS"]

    mapper = FrameMapper(mapping)
    stats = ScanStats()
    recv = 0.0
    first_us = None
    for ts_us, msgid, sysid, compid, payload, _start, _end in scan_tlog_bytes(path.read_bytes(), stats):
        if first_us is None:
            first_us = ts_us
        if msgid == battery_status:
            col.battery_status_messages += 1
        recv = (ts_us - first_us) / 1e6  # seconds from the log's first record
        frames = mapper.feed(recv, msgid, sysid, compid, payload)
        if frames:
            latest = max(f.time_s for f in frames)
            for f in frames:
                col(f, recv - (latest - f.time_s))
    for f in mapper.flush():
        col(f, recv)
    if stats.bad_crc or stats.garbage_bytes or stats.truncated_tail_bytes:
        log.warning("%s: skipped %d bad-CRC packets, %d garbage bytes, %d truncated tail bytes", path.name,
                    stats.bad_crc, stats.garbage_bytes, stats.truncated_tail_bytes)


def read_tlog(path: str | Path, kind: str, vehicle: "VehicleDescription",
              packs: tuple[str, ...] | None = None) -> list[Flight]:
    """Battery flights (one per pack in ``packs``, default all of the ``vehicle`` description's) or
    the motor flight of one tlog. The description's packs (by BATTERY_STATUS id) and motors (by ESC
    index) are read, named as it names them (``edge540``: the paper's four packs at ids 0-3)."""
    from gcs_pdm.mavlink.vehicle_mapping import frame_mapping

    path = Path(path)
    if not path.is_file():
        raise FlightDataError(f"{path}: no such file")
    packs = vehicle.pack_names if packs is None else packs
    ids = {p.name: p.mavlink_battery_id for p in vehicle.packs}
    col = _FrameCollector(tuple(ids))
    _collect_tlog(path, col, frame_mapping(vehicle))
    if not col.ambient:
        raise FlightDataError(f"{path}: no ambient temperature frames in the tlog")
    amb = np.array(col.ambient, dtype=np.float64)
    out: list[Flight] = []
    if kind == BATTERY:
        for p in packs:
            rows = np.array(col.packs[p], dtype=np.float64).reshape(-1, 4)
            if rows.shape[0] == 0:
                raise FlightDataError(
                    f"{path}: no frames for pack {p} (BATTERY_STATUS id {ids[p]} from the vehicle; "
                    f"the log holds {col.battery_status_messages} BATTERY_STATUS messages in all; "
                    "a per-pack fit needs per-pack battery telemetry)")
            t = rows[:, 0]
            out.append(flight_from_columns(f"{path.stem}_{p}", BATTERY, {
                "time_s": t, "current_a": rows[:, 1], "voltage_v": rows[:, 2], "temperature_c": rows[:, 3],
                "ambient_c": _interp(t, amb[:, 0], amb[:, 1])}, source={"file": str(path), "pack": p}))
    else:
        if not col.motors:
            raise FlightDataError(f"{path}: no motor frames in the tlog")
        series = {m: np.array(r, dtype=np.float64).reshape(-1, 3) for m, r in col.motors.items()}
        t = max(series.values(), key=len)[:, 0]
        cur = np.nanmean([_interp(t, s[:, 0], s[:, 1]) for s in series.values()], axis=0)
        temps = np.array([_interp(t, s[:, 0], s[:, 2]) for s in series.values()])
        with warnings.catch_warnings():  # a time with no temperature from either motor stays missing
            warnings.simplefilter("ignore", RuntimeWarning)
            temp = np.nanmean(temps, axis=0)
        out.append(flight_from_columns(f"{path.stem}_motor", MOTOR, {
            "time_s": t, "current_a": cur, "temperature_c": temp, "ambient_c": _interp(t, amb[:, 0], amb[:, 1])},
            source={"file": str(path), "motors": sorted(series)}))
    return out


def read_flights(path: str | Path, kind: str, pack: str = "all", *,
                 vehicle: "VehicleDescription") -> list[Flight]:
    """Flights of one file: a table gives one (its pack is the file's); a log gives one per pack of
    the ``vehicle`` description (``pack="all"``) or the named pack, or the motor flight. The packs
    are the description's: a tlog's by BATTERY_STATUS id, an autopilot log's by DataFlash/battery
    instance."""
    if kind not in KINDS:
        raise FlightDataError(f"kind must be one of {KINDS}, got {kind!r}")
    path = Path(path)
    suffix = path.suffix.lower()
    names = vehicle.pack_names
    packs = names if pack == "all" else (pack,)
    if suffix in TLOG_SUFFIXES + AUTOPILOT_LOG_SUFFIXES:
        bad = [p for p in packs if p not in names]
        if bad:
            raise FlightDataError(f"unknown pack {bad[0]!r}; expected one of {', '.join(names)} or all")
    if suffix in TLOG_SUFFIXES + AUTOPILOT_LOG_SUFFIXES and path.is_file():
        from gcs_pdm.logs.kind import NotALog, log_kind

        try:  # a file that is no log is told so, as every command tells it (docs/cli.md)
            log_kind(path)
        except NotALog as exc:
            raise FlightDataError(str(exc)) from None
    if suffix in TLOG_SUFFIXES:
        return read_tlog(path, kind, vehicle, packs)
    if suffix in AUTOPILOT_LOG_SUFFIXES:
        from gcs_pdm.logs.reader import read_log
        from gcs_pdm.logs.series import motor_flight

        if not path.is_file():
            raise FlightDataError(f"{path}: no such file")
        series = read_log(path)
        if kind != BATTERY:
            return [motor_flight(series)]
        return [_described_pack_flight(series, spec) for spec in vehicle.packs if spec.name in packs]
    if suffix in TABLE_SUFFIXES:
        return [read_table(path, kind)]
    raise FlightDataError(f"{path}: unknown flight file type {path.suffix!r} "
                          "(use .csv, .parquet, .tlog, .bin or .ulg)")


def _described_pack_flight(series, spec) -> Flight:
    """A description's pack from an autopilot log: its DataFlash instance (default: its MAVLink id)."""
    import dataclasses

    from gcs_pdm.logs.series import battery_flights

    instance = spec.dataflash_instance if spec.dataflash_instance is not None else spec.mavlink_battery_id
    if instance not in series.batteries:
        have = ", ".join(str(i) for i in sorted(series.batteries)) or "none"
        raise FlightDataError(f"{series.path}: no battery instance {instance} for pack {spec.name} in the "
                              f"{series.autopilot} log; it has instances {have}")
    flight = battery_flights(series, series.pack_name(instance))[0]
    return dataclasses.replace(flight, name=f"{series.path.stem}_{spec.name}",
                               source={**flight.source, "pack": spec.name})


def write_table(flight: Flight, path: str | Path) -> Path:
    """A flight as a CSV or Parquet table with the standard columns."""
    import pandas as pd

    path = Path(path)
    df = pd.DataFrame({c: getattr(flight, c) for c in flight.columns()})
    if path.suffix.lower() == ".csv":
        df.to_csv(path, index=False)
    else:
        df.to_parquet(path, index=False)
    return path


def safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def write_outputs(result: "FitResult", out_dir: str | Path, plots: bool = True) -> dict[str, Path]:
    """``result.json``, ``predictions/<flight>.csv`` for every flight and ``plots/<flight>.png`` for
    every test flight (predicted vs measured, like the paper's Figures 3 and 4)."""
    import pandas as pd

    out = Path(out_dir)
    (out / "predictions").mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    res_path = out / "result.json"
    res_path.write_text(json.dumps(result.to_dict(), indent=2, allow_nan=False))
    written["result"] = res_path
    for p in result.predictions:
        cols = {"time_s": p.time_s}
        if p.measured_voltage is not None:
            cols.update(measured_voltage_v=p.measured_voltage, predicted_voltage_v=p.predicted_voltage,
                        reference_voltage_v=p.reference_voltage)
        cols.update(measured_temperature_c=p.measured_temperature, predicted_temperature_c=p.predicted_temperature,
                    reference_temperature_c=p.reference_temperature)
        fp = out / "predictions" / f"{safe_name(p.name)}.csv"
        pd.DataFrame(cols).assign(split=p.split).to_csv(fp, index=False)
        written[f"predictions/{p.name}"] = fp
    if plots:
        from gcs_pdm.fitting.plots import plot_flight

        (out / "plots").mkdir(exist_ok=True)
        for p in result.predictions:
            if p.split == "test":
                fp = out / "plots" / f"{safe_name(p.name)}.png"
                plot_flight(p, fp, reference=result.reference)
                written[f"plots/{p.name}"] = fp
    return written
