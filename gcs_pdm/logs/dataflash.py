"""ArduPilot DataFlash ``.bin`` logs, read in bulk into numpy arrays.

Format (ArduPilot's AP_Logger, as pymavlink's DFReader reads it): a stream of messages, each
``0xA3 0x95 <type>`` followed by a fixed-length payload. Type 128 (FMT) defines every other type:
its id, total length, four-character name, a format string (one character per column: ``Q``
uint64, ``f`` float, ``c`` int16 x 0.01, ``L`` int32 x 1e-7 degrees, ``Z`` 64 chars ...) and the
column names. FMT messages precede the first use of their type but may appear anywhere.

DFReader decodes message by message in Python (~1.5 µs per byte of log, see
benchmarks/bench_logs.py). Here one pass (compiled with numba) finds where every message starts,
learning lengths from FMT messages on the way and resynchronising over garbage; then each wanted
type is cut out of the buffer with one fancy index and viewed as a numpy structured array. Scaled
columns (``c C e E L``) come out as float64 in their natural unit.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcs_pdm.logs.tables import FlightDataError

log = logging.getLogger(__name__)

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 128
FMT_LENGTH = 89  # 3 header + type, length, name[4], format[16], columns[64]

# format character -> (numpy type, scale applied when decoded, or None for raw)
_FORMAT_CHARS: dict[str, tuple[str, float | None]] = {
    "a": ("(32,)<i2", None), "b": ("i1", None), "B": ("u1", None), "h": ("<i2", None), "H": ("<u2", None),
    "i": ("<i4", None), "I": ("<u4", None), "f": ("<f4", None), "d": ("<f8", None), "n": ("S4", None),
    "N": ("S16", None), "Z": ("S64", None), "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01),
    "E": ("<u4", 0.01), "L": ("<i4", 1e-7), "M": ("u1", None), "q": ("<i8", None), "Q": ("<u8", None),
    "g": ("<f2", None),
}


class DataFlashError(FlightDataError):
    """A file that is not a readable DataFlash log; the message says why."""


@dataclass(frozen=True)
class MessageFormat:
    type: int
    length: int
    name: str
    format: str
    columns: tuple[str, ...]

    def dtype(self) -> np.dtype:
        names, types = ["_head"], ["S3"]
        for col, ch in zip(self.columns, self.format):
            if ch not in _FORMAT_CHARS:
                raise DataFlashError(f"{self.name}: unknown format character {ch!r}")
            names.append(col)
            types.append(_FORMAT_CHARS[ch][0])
        dt = np.dtype({"names": names, "formats": types})
        if dt.itemsize != self.length:
            raise DataFlashError(f"{self.name}: format {self.format!r} is {dt.itemsize} bytes, FMT says {self.length}")
        return dt


@dataclass
class DataFlashLog:
    """Message starts and formats of one log; :meth:`messages` decodes one type in bulk."""

    path: Path
    data: np.ndarray  # uint8 buffer
    starts: np.ndarray  # offset of every message
    types: np.ndarray  # its type id
    formats: dict[str, MessageFormat]
    skipped_bytes: int
    _cache: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        ids, n = np.unique(self.types, return_counts=True)
        by_id = {f.type: f.name for f in self.formats.values()}
        return {by_id.get(int(i), f"type{int(i)}"): int(c) for i, c in zip(ids, n)}

    def has(self, name: str) -> bool:
        return name in self.formats and bool(np.any(self.types == self.formats[name].type))

    def messages(self, name: str) -> dict[str, np.ndarray]:
        """Every ``name`` message as columns (scaled to natural units; strings as ``str``)."""
        if name in self._cache:
            return self._cache[name]
        fmt = self.formats.get(name)
        if fmt is None:
            return {}
        at = self.starts[self.types == fmt.type]
        at = at[at + fmt.length <= self.data.size]
        dt = fmt.dtype()
        raw = self.data[at[:, None] + np.arange(fmt.length)].reshape(-1).view(dt) if at.size else np.zeros(0, dt)
        out: dict[str, np.ndarray] = {}
        for col, ch in zip(fmt.columns, fmt.format):
            values = raw[col]
            scale = _FORMAT_CHARS[ch][1]
            if scale is not None:
                values = values.astype(np.float64) * scale
            elif ch in "nNZ":
                values = np.char.decode(np.char.rstrip(values, b"\x00"), "ascii", "replace")
            out[col] = values
        self._cache[name] = out
        return out


def _compiled_scan():
    import numba

    @numba.njit(cache=True)
    def scan(data, lengths):
        n = data.size
        starts = np.empty(n // 4 + 1, np.int64)
        types = np.empty(n // 4 + 1, np.uint8)
        count, pos, skipped = 0, 0, 0
        while pos + 3 <= n:
            t = data[pos + 2]
            if data[pos] == HEAD1 and data[pos + 1] == HEAD2 and lengths[t] > 0:
                if pos + lengths[t] > n:
                    break
                if t == FMT_TYPE:
                    lengths[data[pos + 3]] = data[pos + 4]
                if count == starts.size:  # messages shorter than 4 bytes (never in practice)
                    break
                starts[count] = pos
                types[count] = t
                count += 1
                pos += lengths[t]
            else:
                pos += 1
                skipped += 1
        return starts[:count], types[:count], skipped

    return scan


_SCAN = None


def read_dataflash(path: str | Path) -> DataFlashLog:
    """Index a DataFlash log: where each message starts, and every FMT it defines."""
    global _SCAN
    path = Path(path)
    if not path.is_file():
        raise DataFlashError(f"{path}: no such file")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size < 3 or data[0] != HEAD1 or data[1] != HEAD2:
        raise DataFlashError(f"{path}: not an ArduPilot DataFlash log (no 0xA3 0x95 message header at the start)")
    if _SCAN is None:
        _SCAN = _compiled_scan()
    lengths = np.zeros(256, np.int64)
    lengths[FMT_TYPE] = FMT_LENGTH
    starts, types, skipped = _SCAN(data, lengths)
    fmt_at = starts[types == FMT_TYPE]
    fmt_at = fmt_at[fmt_at + FMT_LENGTH <= data.size]
    rows = data[fmt_at[:, None] + np.arange(FMT_LENGTH)].reshape(-1).view(
        np.dtype([("_h", "S3"), ("type", "u1"), ("length", "u1"), ("name", "S4"), ("format", "S16"),
                  ("columns", "S64")]))
    formats: dict[str, MessageFormat] = {}
    for r in rows:
        name = r["name"].rstrip(b"\x00").decode("ascii", "replace")
        cols = tuple(c for c in r["columns"].rstrip(b"\x00").decode("ascii", "replace").split(",") if c)
        fmt = r["format"].rstrip(b"\x00").decode("ascii", "replace")
        formats[name] = MessageFormat(int(r["type"]), int(r["length"]), name, fmt, cols)
    if skipped:
        log.warning("%s: skipped %d bytes that were not DataFlash messages", path.name, skipped)
    return DataFlashLog(path, data, starts, types, formats, int(skipped))


def _time_s(cols: dict[str, np.ndarray], t0_us: int) -> np.ndarray:
    return (cols["TimeUS"].astype(np.int64) - t0_us) / 1e6


def _instance(cols: dict[str, np.ndarray]) -> np.ndarray:
    for name in ("Inst", "Instance", "I"):
        if name in cols:
            return cols[name].astype(np.int64)
    return np.zeros(next(iter(cols.values())).size, np.int64)


def _unmeasured_zero(values: np.ndarray) -> np.ndarray:
    """ArduPilot logs 0 for a temperature its sensor does not have: missing, not 0 °C."""
    values = values.astype(np.float64)
    return np.where(values == 0.0, np.nan, values)


def series_from_dataflash(path: str | Path):
    """The powertrain, air data, position, modes, commands and messages of an ArduPilot log."""
    from gcs_pdm.logs.series import BatterySeries, EscSeries, LogSeries

    df = read_dataflash(path)
    timed = [df.messages(n)["TimeUS"] for n in ("BAT", "ESC", "BARO", "GPS", "ARSP", "CTUN", "POWR")
             if df.has(n) and "TimeUS" in df.formats[n].columns]
    if not timed or not any(t.size for t in timed):
        raise DataFlashError(f"{path}: no timed battery, ESC, barometer or GPS messages in the log")
    t0 = int(min(int(t.min()) for t in timed if t.size))
    out = LogSeries(Path(path), "ArduPilot")
    if df.has("BAT"):
        bat = df.messages("BAT")
        inst, t = _instance(bat), _time_s(bat, t0)
        for i in np.unique(inst):
            m = inst == i
            temp = _unmeasured_zero(bat["Temp"][m]) if "Temp" in bat else np.full(m.sum(), np.nan)
            out.batteries[int(i)] = BatterySeries(
                int(i), t[m], bat["Volt"][m].astype(np.float64), bat["Curr"][m].astype(np.float64), temp,
                bat["CurrTot"][m].astype(np.float64) if "CurrTot" in bat else np.full(m.sum(), np.nan))
            if np.isnan(temp).all():
                out.missing[f"battery{int(i)}.temperature_c"] = "BAT.Temp is 0 throughout: the monitor has no sensor"
    if df.has("BCL"):  # cell voltages: only the cell count is used (a reported cell is > 0 and not 0xFFFF)
        bcl = df.messages("BCL")
        inst = _instance(bcl)
        for i in np.unique(inst):
            cells = [c for c in bcl if c.startswith("V") and c[1:].isdigit()]
            row = np.array([bcl[c][inst == i][-1] for c in cells])
            if int(i) in out.batteries:
                out.batteries[int(i)].cells = int(((row > 0) & (row < 0xFFFF)).sum()) or None
    if df.has("ESC"):
        esc = df.messages("ESC")
        inst, t = _instance(esc), _time_s(esc, t0)
        for i in np.unique(inst):
            m = inst == i
            out.escs[int(i)] = EscSeries(int(i), t[m], esc["RPM"][m].astype(np.float64),
                                         esc["Curr"][m].astype(np.float64), _unmeasured_zero(esc["Temp"][m]))
    if df.has("BARO"):
        baro = df.messages("BARO")
        first = _instance(baro) == 0
        out.ambient = (_time_s(baro, t0)[first], baro["Temp"][first].astype(np.float64))
    else:
        out.missing["ambient_c"] = "no BARO messages"
    if df.has("GPS"):
        gps = df.messages("GPS")
        first = (_instance(gps) == 0) & (gps["Status"] >= 3)  # a 3D fix
        course = np.radians(gps["GCrs"][first].astype(np.float64))
        speed = gps["Spd"][first].astype(np.float64)
        out.position = {"time_s": _time_s(gps, t0)[first], "lat_deg": gps["Lat"][first], "lon_deg": gps["Lng"][first],
                        "alt_m": gps["Alt"][first], "vn": speed * np.cos(course), "ve": speed * np.sin(course),
                        "vd": -gps["VZ"][first].astype(np.float64)}  # GPS.VZ is up-positive in AP_GPS logs
    if df.has("ARSP"):
        arsp = df.messages("ARSP")
        first = _instance(arsp) == 0
        out.airspeed = (_time_s(arsp, t0)[first], arsp["Airspeed"][first].astype(np.float64))
    # the EKF's wind: XKF2 (EKF3) or NKF2 (EKF2) VWN/VWE, the air's velocity; the primary core (C = 0)
    for name in ("XKF2", "NKF2"):
        if df.has(name) and {"VWN", "VWE"} <= set(df.formats[name].columns):
            kf = df.messages(name)
            core = kf["C"] == 0 if "C" in kf else np.ones(kf["VWN"].shape, dtype=bool)
            out.wind = (_time_s(kf, t0)[core], kf["VWN"][core].astype(np.float64), kf["VWE"][core].astype(np.float64))
            break
    else:
        out.missing["wind"] = "no XKF2 or NKF2 messages (the EKF's wind estimate)"
    if df.has("MSG"):
        msg = df.messages("MSG")
        out.texts = [(float(t), str(s)) for t, s in zip(_time_s(msg, t0), msg["Message"])]
    if df.has("PARM"):  # a parameter set in flight is logged again: the last value wins
        parm = df.messages("PARM")
        out.parameters = {str(n): float(v) for n, v in zip(parm["Name"], parm["Value"])}
    if df.has("VER"):
        ver = df.messages("VER")
        out.firmware = str(ver["FWS"][-1]) if "FWS" in ver else None
        out.build = int(ver["BU"][-1]) if "BU" in ver else None
    if out.firmware is None:  # older logs: the banner is the first message
        out.firmware = next((text for _, text in out.texts[:5] if text.startswith(("Ardu", "Rover", "Blimp"))), None)
    if df.has("MODE"):
        mode = df.messages("MODE")
        names = _mode_names(out.texts)
        out.modes = [(float(t), names.get(int(m), f"mode {int(m)}")) for t, m in zip(_time_s(mode, t0), mode["Mode"])]
    # CMD: the stored mission as logged (at arming); MISE: each item as the vehicle starts it
    for name, target in (("CMD", out.mission), ("MISE", out.commands)):
        if df.has(name):
            c = df.messages(name)
            target += [(float(t), int(n), int(i)) for t, n, i in zip(_time_s(c, t0), c["CNum"], c["CId"])]
    return out


def _mode_names(texts: list[tuple[float, str]]) -> dict[int, str]:
    """Flight mode numbers -> names for the vehicle the log's banner names (ArduPlane if none)."""
    from gcs_pdm.mavlink.dialect import mavutil

    banner = " ".join(text for _, text in texts[:5])
    if "ArduCopter" in banner:
        return dict(mavutil.mode_mapping_acm)
    if "Rover" in banner:
        return dict(mavutil.mode_mapping_rover)
    return dict(mavutil.mode_mapping_apm)
