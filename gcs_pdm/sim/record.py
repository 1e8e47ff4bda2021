"""Fly a simulated mission in lock-step, without a network, and record it as a tlog.

The tlog format is the one ``gcs_pdm.mavlink.tlog`` reads: per record an 8-byte big-endian
timestamp in µs, then the raw MAVLink 2 packet. The timestamp is the vehicle's simulated time
plus a fixed boot epoch, so the same config and seed give the same bytes.
"""
from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.sim.core import VehicleCore
from gcs_pdm.sim.model import Event, SimConfig, TruthState
from gcs_pdm.sim.telemetry import COMPONENT_ID, SYSTEM_ID, TelemetryConfig

log = logging.getLogger(__name__)

_TIMESTAMP = struct.Struct(">Q")

#: truth series sampled by ``fly``: name -> TruthState attribute
TRUTH_SERIES = ("pack_voltage_v", "pack_current_a", "pack_temp_c", "pack_soc", "motor_current_a", "motor_temp_c",
                "ambient_c", "shaft_power_w", "rpm", "alt_m", "airspeed_mps", "climb_mps", "energy_j")


class _Sink:
    """A file-like target for pymavlink's encoder that keeps each packet."""

    def __init__(self) -> None:
        self.packets: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.packets.append(bytes(data))


@dataclass
class FlightRecord:
    """A flown mission: the truth at every ``truth_every_s`` and what the vehicle reported."""

    time_s: np.ndarray
    truth: dict[str, np.ndarray]
    events: list[Event]
    fault_log: list[dict]
    reached: list[tuple[int, float]]
    final: TruthState
    messages: dict[str, int] = field(default_factory=dict)
    tlog_path: Path | None = None
    tlog_bytes: int = 0

    @property
    def failed(self) -> bool:
        return self.final.failed


def fly(config: SimConfig, telemetry: TelemetryConfig | None = None, tlog_path: str | Path | None = None, *,
        max_time_s: float = 4 * 3600.0, tail_s: float = 10.0, truth_every_s: float = 1.0) -> FlightRecord:
    """Fly ``config``'s mission to its end (landed or failed, plus ``tail_s`` on the ground) as fast as
    the CPU allows; write every packet the vehicle sends to ``tlog_path`` if given."""
    core = VehicleCore(config, telemetry)
    sink = _Sink()
    mav = mavlink2.MAVLink(sink, srcSystem=SYSTEM_ID, srcComponent=COMPONENT_ID)
    boot_us = core.telemetry.config.boot_unix_us
    records: list[bytes] = []
    counts: dict[str, int] = {}
    times: list[float] = []
    series: dict[str, list] = {k: [] for k in TRUTH_SERIES}
    next_truth = 0.0
    end_at = None
    while core.time_s < max_time_s:
        msgs = core.tick()
        stamp = _TIMESTAMP.pack(boot_us + int(round(core.time_s * 1e6)))
        for msg in msgs:
            mav.send(msg)
            records.append(stamp + sink.packets.pop())
            counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
        s = core.last_state
        if s.time_s + 1e-9 >= next_truth:
            next_truth += truth_every_s
            times.append(s.time_s)
            for k in TRUTH_SERIES:
                series[k].append(getattr(s, k))
        if end_at is None and core.model.finished:
            end_at = core.time_s + tail_s
        if end_at is not None and core.time_s >= end_at:
            break
    else:
        log.warning("flight not finished after %.0f s of simulated time", max_time_s)
    size = 0
    path = None
    if tlog_path is not None:
        path = Path(tlog_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = b"".join(records)
        path.write_bytes(data)
        size = len(data)
    m = core.model
    return FlightRecord(np.asarray(times), {k: np.asarray(v) for k, v in series.items()}, list(core.event_log),
                        list(m.fault_log), list(m.reached_log), core.last_state, counts, path, size)
