"""What the simulated vehicle says: truth snapshots and events → MAVLink 2 messages, as on the wire.

Periodic telemetry is scheduled in *simulated* time at configurable rates; values get seeded sensor
noise and the wire's integer quantisation (mV, cA, cdegC, 1e-7 deg…), and any periodic message can
be lost (seeded drop-outs, plus optional outage windows). Event messages (MISSION_ITEM_REACHED,
MISSION_CURRENT on change, STATUSTEXT) are never dropped here: a lossy radio is the job of a relay
in front of the vehicle, as in the link's tests.

Wire choices the link maps (``gcs_pdm.mavlink.mapping.DEFAULT_MAPPING``):

* BATTERY_STATUS id 0..3 = LLF20, ULA20, LRF40, URA40; ``voltages[0]`` = the whole pack's terminal
  voltage in mV, the other nine cells UINT16_MAX ("no cell"), as ArduPilot sends a monitor without
  cell sensing; ``current_battery`` cA (discharge positive); ``temperature`` cdegC.
* ESC_TELEMETRY_1_TO_4 index 0 = fwd motor, 1 = aft: ``voltage`` cV (the motor's string voltage),
  ``current`` cA, ``rpm`` (one shaft: both the same), ``temperature`` °C (the shared bracket sensor
  of the paper reads each motor here).
* SCALED_PRESSURE ``temperature`` = ambient air, cdegC; every ``time_boot_ms`` is simulated time.
* A described vehicle (``SimConfig.vehicle``) sends its own layout instead: BATTERY_STATUS at each
  pack's ``mavlink_battery_id`` (temperature INT16_MAX when the pack has no sensor), each motor at
  its ESC index (ESC_TELEMETRY_5_TO_8 … above 3; readings it lacks as 0), its HEARTBEAT type
  (fixed wing, quad, hexa …) and, for a multirotor, ArduCopter's mode numbers.

Pure: no sockets or clocks; the caller passes the simulated time and a seeded generator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.sim.model import COPTER_MODES, PLANE_MODES, Event, TruthState

SYSTEM_ID = 1
COMPONENT_ID = 1
UINT16_MAX = 65535
INT16_MAX = 32767

#: default rates, Hz (live vehicle)
DEFAULT_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "SYSTEM_TIME": 0.2,
    "BATTERY_STATUS": 2.0,
    "ESC_TELEMETRY_1_TO_4": 2.0,
    "SCALED_PRESSURE": 1.0,
    "GLOBAL_POSITION_INT": 4.0,
    "VFR_HUD": 4.0,
    "MISSION_CURRENT": 1.0,
    "WIND": 1.0,
}

#: thinner rates for recorded fixtures (1 Hz battery/ESC telemetry keeps a 30 min flight small)
RECORDING_RATES: dict[str, float] = {
    "HEARTBEAT": 0.2,
    "SYS_STATUS": 0.1,
    "SYSTEM_TIME": 0.05,
    "BATTERY_STATUS": 1.0,
    "ESC_TELEMETRY_1_TO_4": 1.0,
    "SCALED_PRESSURE": 0.2,
    "GLOBAL_POSITION_INT": 0.2,
    "VFR_HUD": 0.2,
    "MISSION_CURRENT": 0.1,
}


@dataclass(frozen=True)
class SensorNoise:
    """1-sigma Gaussian sensor noise, before quantisation."""

    voltage_v: float = 0.02
    current_a: float = 0.08
    temperature_c: float = 0.2
    rpm: float = 15.0
    airspeed_mps: float = 0.3
    position_m: float = 1.0
    alt_m: float = 0.5
    wind_mps: float = 0.3  # the autopilot's wind estimate, per component


@dataclass(frozen=True)
class TelemetryConfig:
    rates_hz: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_RATES))
    noise: SensorNoise = SensorNoise()
    drop_rate: float = 0.01  # probability that any one periodic message is lost
    outages: tuple[tuple[float, float], ...] = ()  # (start s, duration s) of total telemetry silence
    #: Unix time of boot (µs) for SYSTEM_TIME; fixed so the same seed gives the same bytes
    boot_unix_us: int = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z
    #: an event's heartbeat (arming, a mode change, landing) only when the state it announces is not
    #: the latest heartbeat's already (arming and the mode change, landing and disarming come as two
    #: events, from one tick or two commands), and it restarts the periodic heartbeat's period: no
    #: two identical heartbeats back to back with nothing between (a duplicate to the link's
    #: heartbeat watch). Off by default: the recorded fixtures keep their bytes; on for a live vehicle.
    event_heartbeat_restarts_period: bool = False

    def __post_init__(self) -> None:
        for name, hz in self.rates_hz.items():
            if name not in DEFAULT_RATES:
                raise ValueError(f"rates_hz: unknown message {name!r}; known: {sorted(DEFAULT_RATES)}")
            if not (hz >= 0 and math.isfinite(hz)):
                raise ValueError(f"rates_hz[{name!r}]: must be a finite rate >= 0 Hz, got {hz!r}")
        if not 0.0 <= self.drop_rate < 1.0:
            raise ValueError(f"drop_rate: must be within [0, 1), got {self.drop_rate!r}")


def _clip_int(x: float, lo: int, hi: int) -> int:
    if not math.isfinite(x):
        return lo
    return int(min(hi, max(lo, round(x))))


def _announces(beat) -> tuple:
    """What a heartbeat announces: the vehicle's mode, arming and status."""
    return beat.custom_mode, beat.base_mode, beat.system_status


def pressure_hpa(alt_amsl_m: float) -> float:
    """ISA static pressure."""
    return 1013.25 * max(0.0, 1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


class Telemetry:
    """Builds the vehicle's messages; one per vehicle, stepping with its simulated time."""

    def __init__(self, config: TelemetryConfig | None = None, seed: int = 0):
        self.config = config or TelemetryConfig()
        self.rng = np.random.default_rng([int(seed), 0x7E1E])
        self.mav = mavlink2.MAVLink(None, srcSystem=SYSTEM_ID, srcComponent=COMPONENT_ID)
        self.rates = {k: float(v) for k, v in self.config.rates_hz.items()}
        # stagger the streams over the first period so they do not all fall on one tick
        self._next: dict[str, float] = {name: 0.0 for name in self.rates}
        self.sent: dict[str, int] = {}
        #: the state the latest heartbeat built announced (``event_heartbeat_restarts_period``)
        self._announced: tuple | None = None
        self.dropped = 0

    def set_rate(self, name: str, hz: float) -> None:
        """Change one stream's rate (SET_MESSAGE_INTERVAL); 0 stops it."""
        if name not in DEFAULT_RATES:
            raise ValueError(f"unknown telemetry message {name!r}")
        self.rates[name] = max(0.0, float(hz))
        self._next.setdefault(name, 0.0)

    # ---- scheduling -----------------------------------------------------------------------

    def periodic(self, s: TruthState) -> list:
        """Messages due at the state's time (after drop-outs)."""
        out = []
        t = s.time_s
        in_outage = any(a <= t < a + d for a, d in self.config.outages)
        for name, hz in self.rates.items():
            if hz <= 0.0 or t + 1e-9 < self._next[name]:
                continue
            period = 1.0 / hz
            nxt = self._next[name] + period
            self._next[name] = nxt if nxt > t else t + period
            msgs = _BUILDERS[name](self, s)
            for msg in msgs:
                if in_outage or (self.config.drop_rate > 0 and self.rng.random() < self.config.drop_rate):
                    self.dropped += 1
                    continue
                out.append(msg)
                self.sent[name] = self.sent.get(name, 0) + 1
        return out

    def events(self, events: list[Event], s: TruthState) -> list:
        """Messages that report events (never dropped)."""
        out = []
        for ev in events:
            if ev.kind == "reached":
                out.append(self.mav.mission_item_reached_encode(ev.seq))
            elif ev.kind == "current":
                out.append(self.mav.mission_current_encode(max(0, ev.seq), s.mission_count, s.mission_state,
                                                           1 if s.mode == "AUTO" else 0))
            elif ev.kind == "statustext":
                out.append(self.mav.statustext_encode(ev.severity, ev.text.encode("utf-8")[:50]))
            elif ev.kind in ("mode", "armed", "disarmed", "landed"):
                beat = self.heartbeat(s)
                if self.config.event_heartbeat_restarts_period:
                    if _announces(beat[0]) == self._announced:
                        continue  # this state is announced already (one heartbeat for the events of a moment)
                    hz = self.rates.get("HEARTBEAT", 0.0)
                    if hz > 0.0:
                        self._next["HEARTBEAT"] = s.time_s + 1.0 / hz
                out.extend(beat)
        return out

    def build(self, name: str, s: TruthState) -> list:
        """One stream's message(s) now, outside the schedule (MAV_CMD_REQUEST_MESSAGE)."""
        return _BUILDERS[name](self, s)

    # ---- message builders -----------------------------------------------------------------

    def _n(self, sigma: float) -> float:
        return float(self.rng.normal(0.0, sigma)) if sigma > 0 else 0.0

    def heartbeat(self, s: TruthState) -> list:
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if s.mode == "AUTO":
            base |= (mavlink2.MAV_MODE_FLAG_AUTO_ENABLED | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
                     | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED)
        elif s.mode == "RTL":
            base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        else:
            base |= mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if s.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        if s.failed:
            status = mavlink2.MAV_STATE_EMERGENCY
        elif s.armed:
            status = mavlink2.MAV_STATE_ACTIVE
        else:
            status = mavlink2.MAV_STATE_STANDBY
        modes = COPTER_MODES if s.multirotor else PLANE_MODES
        beat = self.mav.heartbeat_encode(s.mav_type, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                                         modes.get(s.mode, 0), status, 3)
        self._announced = _announces(beat)
        return [beat]

    def sys_status(self, s: TruthState) -> list:
        sensors = (mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                   | mavlink2.MAV_SYS_STATUS_SENSOR_GPS | mavlink2.MAV_SYS_STATUS_SENSOR_BATTERY)
        health = sensors if not s.failed else sensors & ~mavlink2.MAV_SYS_STATUS_SENSOR_BATTERY
        bus = float(s.motor_voltage_v[0]) + self._n(self.config.noise.voltage_v)
        cur = float(s.motor_current_a.sum()) + self._n(self.config.noise.current_a)
        return [self.mav.sys_status_encode(sensors, sensors, health, 250, _clip_int(bus * 1000, 0, UINT16_MAX - 1),
                                           _clip_int(cur * 100, -1, 32767),
                                           _clip_int(100 * float(s.pack_soc.min()), 0, 100), 0, 0, 0, 0, 0, 0)]

    def system_time(self, s: TruthState) -> list:
        return [self.mav.system_time_encode(self.config.boot_unix_us + int(round(s.time_s * 1e6)),
                                            int(round(s.time_s * 1000)))]

    def battery_status(self, s: TruthState) -> list:
        nz = self.config.noise
        out = []
        for i, battery_id in enumerate(s.pack_ids):
            v = float(s.pack_voltage_v[i]) + self._n(nz.voltage_v)
            cur = float(s.pack_current_a[i]) + (self._n(nz.current_a) if s.armed else 0.0)
            temp = float(s.pack_temp_c[i]) + self._n(nz.temperature_c)
            voltages = [_clip_int(v * 1000, 0, UINT16_MAX - 1)] + [UINT16_MAX] * 9
            # a monitor without a temperature sensor sends INT16_MAX, as ArduPilot does
            wire_temp = _clip_int(temp * 100, -32767, 32766) if s.pack_reports_temperature[i] else INT16_MAX
            out.append(self.mav.battery_status_encode(
                battery_id, mavlink2.MAV_BATTERY_FUNCTION_PROPULSION, mavlink2.MAV_BATTERY_TYPE_LIPO,
                wire_temp, voltages, _clip_int(cur * 100, -32767, 32767),
                _clip_int(float(s.pack_charge_c[i]) / 3.6, 0, 2**31 - 1),
                _clip_int(float(s.pack_energy_j[i]) / 100.0, 0, 2**31 - 1),
                _clip_int(100 * float(s.pack_soc[i]), 0, 100)))
        return out

    def esc(self, s: TruthState) -> list:
        """ESC_TELEMETRY_1_TO_4 (and 5_TO_8, … for higher ESC indices): each motor at its index, the
        other indices zero, a reading the ESC does not have zero too (as ArduPilot sends them)."""
        nz = self.config.noise
        blocks: dict[int, list[list[int]]] = {}
        shaft_rpm = s.rpm + (self._n(nz.rpm) if s.rpm > 0 else 0.0)
        for q, index in enumerate(s.esc_index):
            temp, volt, cur, total, rpm = blocks.setdefault(index // 4, [[0] * 4 for _ in range(5)])
            k = index % 4
            has_current, has_rpm, has_temp = s.motor_readings[q]
            if has_temp:
                temp[k] = _clip_int(float(s.motor_temp_c[q]) + self._n(nz.temperature_c), 0, 255)
            volt[k] = _clip_int((float(s.motor_voltage_v[q]) + self._n(nz.voltage_v)) * 100, 0, UINT16_MAX)
            if has_current:
                c = float(s.motor_current_a[q]) + (self._n(nz.current_a) if s.armed else 0.0)
                cur[k] = _clip_int(c * 100, 0, UINT16_MAX)
            # the paper's strings: a motor's string carries its current, so its first pack's charge
            charge = s.pack_charge_c[q] if s.motor_charge_c is None else s.motor_charge_c[q]
            total[k] = _clip_int(float(charge) / 3.6, 0, UINT16_MAX)
            if has_rpm:
                rpm[k] = _clip_int(shaft_rpm, 0, UINT16_MAX)
        encoders = (self.mav.esc_telemetry_1_to_4_encode, self.mav.esc_telemetry_5_to_8_encode,
                    self.mav.esc_telemetry_9_to_12_encode)
        return [encoders[b](*blocks[b], [0] * 4) for b in sorted(blocks)]

    def scaled_pressure(self, s: TruthState) -> list:
        nz = self.config.noise
        p = pressure_hpa(s.alt_amsl_m + self._n(nz.alt_m))
        q = 0.5 * s.air_density * s.airspeed_mps ** 2 / 100.0
        return [self.mav.scaled_pressure_encode(int(round(s.time_s * 1000)), p, q,
                                                _clip_int((s.ambient_c + self._n(nz.temperature_c)) * 100,
                                                          -32767, 32767))]

    def global_position(self, s: TruthState) -> list:
        nz = self.config.noise
        de, dn = self._n(nz.position_m), self._n(nz.position_m)
        lat = s.lat_deg + math.degrees(dn / 6_371_000.0)
        lon = s.lon_deg + math.degrees(de / (6_371_000.0 * math.cos(math.radians(s.lat_deg))))
        alt_noise = self._n(nz.alt_m)
        return [self.mav.global_position_int_encode(
            int(round(s.time_s * 1000)), int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round((s.alt_amsl_m + alt_noise) * 1000)), int(round((s.alt_m + alt_noise) * 1000)),
            _clip_int(s.vel_north_mps * 100, -32767, 32767), _clip_int(s.vel_east_mps * 100, -32767, 32767),
            _clip_int(-s.climb_mps * 100, -32767, 32767), _clip_int(s.heading_deg * 100, 0, 35999))]

    def vfr_hud(self, s: TruthState) -> list:
        nz = self.config.noise
        air = max(0.0, s.airspeed_mps + (self._n(nz.airspeed_mps) if s.airspeed_mps > 0 else 0.0))
        throttle = _clip_int(100.0 * s.shaft_power_w / 3000.0, 0, 100)
        return [self.mav.vfr_hud_encode(air, s.groundspeed_mps, _clip_int(s.heading_deg, 0, 359), throttle,
                                        s.alt_amsl_m, s.climb_mps)]

    def wind(self, s: TruthState) -> list:
        """ArduPilot's WIND: where the wind blows FROM (degrees, -180..180 as ArduPilot sends it) and
        its speed; the estimate a wind-estimating EKF makes of the wind in force, with its noise."""
        we = s.wind_east_mps + self._n(self.config.noise.wind_mps)
        wn = s.wind_north_mps + self._n(self.config.noise.wind_mps)
        direction = math.degrees(math.atan2(-we, -wn))
        return [self.mav.wind_encode(direction, math.hypot(we, wn), 0.0)]

    def mission_current(self, s: TruthState) -> list:
        return [self.mav.mission_current_encode(s.current_seq, s.mission_count, s.mission_state,
                                                1 if s.mode == "AUTO" else 0)]


_BUILDERS = {
    "HEARTBEAT": Telemetry.heartbeat,
    "SYS_STATUS": Telemetry.sys_status,
    "SYSTEM_TIME": Telemetry.system_time,
    "BATTERY_STATUS": Telemetry.battery_status,
    "ESC_TELEMETRY_1_TO_4": Telemetry.esc,
    "SCALED_PRESSURE": Telemetry.scaled_pressure,
    "GLOBAL_POSITION_INT": Telemetry.global_position,
    "VFR_HUD": Telemetry.vfr_hud,
    "MISSION_CURRENT": Telemetry.mission_current,
    "WIND": Telemetry.wind,
}

