"""Typed telemetry frames: what the rest of gcs-pdm sees of the vehicle.

Pure core: no I/O. Every frame is a small frozen dataclass in SI units (°C for temperatures),
stamped with ``time_s`` — the *message* time in seconds on the vehicle's clock (see
``docs/mavlink.md`` for how that clock is kept), never the wall clock of this process.
A value the vehicle reports as "not available" is ``None``, never a sentinel number.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Union

from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES  # noqa: F401 (the one definition)


@dataclass(frozen=True, slots=True)
class PackFrame:
    """One battery pack: terminal voltage, discharge current (positive = discharging), temperature."""

    time_s: float
    pack: str
    voltage_v: float | None
    current_a: float | None
    temperature_c: float | None


@dataclass(frozen=True, slots=True)
class MotorFrame:
    """One motor (through its ESC): current, shaft speed, temperature."""

    time_s: float
    motor: str
    current_a: float | None
    rpm: float | None
    temperature_c: float | None


@dataclass(frozen=True, slots=True)
class AmbientFrame:
    """Ambient (outside air) temperature."""

    time_s: float
    temperature_c: float | None


@dataclass(frozen=True, slots=True)
class PositionFrame:
    """Global position: WGS84 degrees, altitudes in m (AMSL and above home), NED velocity in m/s."""

    time_s: float
    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    relative_alt_m: float | None
    vn: float | None
    ve: float | None
    vd: float | None


@dataclass(frozen=True, slots=True)
class AirdataFrame:
    """Air data as the HUD shows it: m/s, m/s, m/s (up positive), percent, degrees."""

    time_s: float
    airspeed: float | None
    groundspeed: float | None
    climb_rate: float | None
    throttle_pct: float | None
    heading_deg: float | None


@dataclass(frozen=True, slots=True)
class WindFrame:
    """The autopilot's wind estimate: speed m/s and the direction it blows FROM, degrees clockwise
    from north in [0, 360) (ArduPilot's WIND convention; PX4's WIND_COV velocity is turned into it)."""

    time_s: float
    speed_mps: float | None
    from_deg: float | None


@dataclass(frozen=True, slots=True)
class StatusFrame:
    """Armed state, flight mode name and MAV_STATE of the vehicle."""

    time_s: float
    armed: bool
    mode: str
    system_status: int


@dataclass(frozen=True, slots=True)
class MissionProgressFrame:
    """Mission progress: the item being flown to, or the item just reached (one of them set)."""

    time_s: float
    current_seq: int | None
    reached_seq: int | None


@dataclass(frozen=True, slots=True)
class StatusTextFrame:
    """A text message from the vehicle (MAV_SEVERITY, 0 = emergency … 7 = debug)."""

    time_s: float
    severity: int
    text: str


Frame = Union[
    PackFrame,
    MotorFrame,
    AmbientFrame,
    PositionFrame,
    AirdataFrame,
    StatusFrame,
    MissionProgressFrame,
    StatusTextFrame,
    WindFrame,
]

# Short names used in the mapping configuration and in replay summaries.
FRAME_KINDS: dict[str, type] = {
    "pack": PackFrame,
    "motor": MotorFrame,
    "ambient": AmbientFrame,
    "position": PositionFrame,
    "airdata": AirdataFrame,
    "status": StatusFrame,
    "mission_progress": MissionProgressFrame,
    "statustext": StatusTextFrame,
    "wind": WindFrame,
}
FRAME_KIND_OF: dict[type, str] = {cls: kind for kind, cls in FRAME_KINDS.items()}
