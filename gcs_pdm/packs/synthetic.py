"""Synthetic flight tlogs of one pack with a known capacity and resistance (tests and
benchmarks/bench_ingest.py; shell: writes files).

A pack of ``cells`` cells resting on its chemistry's curve, the one its capacity is read on
(:func:`gcs_pdm.packs.cell_curves.rested_cell_voltage`; a ``liion`` pack has lost lithium), with an
ohmic resistance: rested and disarmed, armed, a climb and a cruise, disarmed, rested again.
The vehicle's HEARTBEAT at 1 Hz, BATTERY_STATUS at 2 Hz, SMART_BATTERY_INFO (serial, rated
capacity, cells) at 0.1 Hz, and ATTITUDE at 10 Hz and GLOBAL_POSITION_INT at 4 Hz as the bulk a
real tlog carries; the ground station's own heartbeat too (system 255, to be ignored).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcs_pdm.packs.cell_curves import capacity_reading, rested_cell_voltage

_STAMP = struct.Struct(">Q")


@dataclass(frozen=True)
class SyntheticPack:
    serial: str = "SYN-0001"
    rated_capacity_ah: float = 5.0
    capacity_ah: float = 5.0          # the truth: what is left of it
    resistance_ohm: float = 0.020     # the pack's (series string's) ohmic resistance
    cells: int = 4
    chemistry: str = "lipo"


def pack_profile(minutes: float = 20.0, rest_before_s: float = 120.0, rest_after_s: float = 600.0,
                 cruise_a: float = 15.0, climb_a: float = 25.0, seed: int = 0):
    """(time_s at 2 Hz, current A, armed) of one flight in a log of ``minutes``."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, minutes * 60.0, 0.5)
    i = np.zeros(t.size)
    fly0, fly1 = rest_before_s, minutes * 60.0 - rest_after_s
    flying = (t >= fly0) & (t < fly1)
    i[flying] = cruise_a * (1.0 + 0.05 * np.sin(t[flying] / 17.0))
    i[(t >= fly0) & (t < fly0 + 60.0)] = climb_a
    for _ in range(3):  # climb bursts
        s = rng.uniform(fly0 + 90.0, fly1 - 60.0)
        i[(t >= s) & (t < s + 20.0)] = climb_a
    armed = (t >= fly0 - 10.0) & (t < fly1 + 10.0)
    return t, i, armed


def write_pack_tlog(path: str | Path, pack: SyntheticPack = SyntheticPack(), *, minutes: float = 20.0,
                    start_soc: float = 1.0, epoch_s: float = 1.7e9, seed: int = 0, bulk: bool = True) -> dict:
    """Write one flight's tlog; the truth (capacity, resistance, charge drawn) as a dict."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    rng = np.random.default_rng(seed)
    t, i, armed = pack_profile(minutes, seed=seed)
    drawn = np.concatenate([[0.0], np.cumsum(0.5 * (i[1:] + i[:-1]) * np.diff(t))]) / 3600.0
    soc = start_soc - drawn / pack.capacity_ah
    reading = capacity_reading(pack.chemistry, pack.rated_capacity_ah)
    ocv = rested_cell_voltage(reading, pack.capacity_ah, drawn + (1.0 - start_soc) * pack.capacity_ah) * pack.cells
    volts = ocv - i * pack.resistance_ohm + rng.normal(0.0, 0.005, t.size)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    out = bytearray()

    def put(ts: float, packet: bytes) -> None:
        out.extend(_STAMP.pack(int(round((epoch_s + ts) * 1e6))))
        out.extend(packet)

    per_cell = min(pack.cells, 10)
    for k in range(t.size):
        ts = float(t[k])
        if k % 2 == 0:
            base = 81 | (128 if armed[k] else 0)
            put(ts, mavlink2.MAVLink_heartbeat_message(2, 3, base, 4, 4, 3).pack(mav))
            put(ts + 0.01, mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(gcs))
        cell_mv = int(round(volts[k] / pack.cells * 1000.0))
        cells = [cell_mv] * per_cell + [65535] * (10 - per_cell)
        put(ts + 0.02, mavlink2.MAVLink_battery_status_message(
            0, 0, 0, 2500, cells, int(round(i[k] * 100.0)), int(drawn[k] * 1000.0), -1,
            int(max(0.0, soc[k]) * 100.0), 0, 0, [0, 0, 0, 0], 0, 0).pack(mav))
        if k % 20 == 0:
            put(ts + 0.03, mavlink2.MAVLink_smart_battery_info_message(
                0, 0, 0, int(pack.rated_capacity_ah * 1000), -1, 65535, pack.serial.encode()[:16], b"synthetic",
                0, 0, 0, 0, 0, pack.cells, 0, 0, b"").pack(mav))
        if bulk:
            for j in range(5):  # ATTITUDE at 10 Hz
                tj = ts + 0.1 * j
                put(tj + 0.04, mavlink2.MAVLink_attitude_message(int(tj * 1000), 0.01, 0.02, 1.0, 0.0, 0.0, 0.0).pack(mav))
            for j in range(2):  # GLOBAL_POSITION_INT at 4 Hz
                tj = ts + 0.25 * j
                put(tj + 0.05, mavlink2.MAVLink_global_position_int_message(
                    int(tj * 1000), 473977420, 85455940, 500000, 20000, 100, 0, 0, 9000).pack(mav))
    Path(path).write_bytes(bytes(out))
    return {"capacity_ah": pack.capacity_ah, "resistance_ohm": pack.resistance_ohm, "drawn_ah": float(drawn[-1]),
            "serial": pack.serial}
