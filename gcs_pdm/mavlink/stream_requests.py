"""Which telemetry streams the service needs, whether the vehicle sends them, and when to ask for
those it does not (pure: no socket, no clock; the shell passes the time and sends the asks).

Some autopilots stream nothing until a ground station asks: ArduCopter on a serial port whose
``SRx_*`` rates are 0 sends its HEARTBEAT and nothing else. Alone beside it the service would
wait for a BATTERY_STATUS forever. So, once the vehicle is identified (its first autopilot
HEARTBEAT), a stream that has not come within ``grace_s`` is asked for:

* ``MAV_CMD_SET_MESSAGE_INTERVAL`` (COMMAND_LONG 511, param1 the message id, param2 the interval in
  µs): MAVLink's own way, in ArduPilot since 3.x and in PX4;
* plus ``REQUEST_DATA_STREAM`` (ArduPilot's older stream groups) once the vehicle has refused
  the command (a COMMAND_ACK other than ACCEPTED and never an ACCEPTED), or after the second ask
  of a stream with no ACCEPTED answer heard at all (firmware that ignores the command).

A stream that does not come is asked again after ``retry_s``, doubling up to ``max_retry_s``
(a vehicle without ESC telemetry is asked now and then, never flooded); one that came and stopped
for ``stale_s`` (or three of its periods, whichever is longer) is asked again from the start. A
stream that comes by itself (the vehicle's configured rates, another ground station's asks) is
never asked for, however slowly it comes: rates that someone set are not overridden.

Time: the shell's receive clock (monotonic seconds). A stream that is missing has no message time
of its own, and the vehicle's clock may not be heard at all before the first asked stream comes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

#: MAV_CMD_SET_MESSAGE_INTERVAL
SET_MESSAGE_INTERVAL = 511
#: MAV_RESULT_ACCEPTED
ACCEPTED = 0
#: MAV_DATA_STREAM_* (REQUEST_DATA_STREAM.req_stream_id)
RAW_SENSORS, EXTENDED_STATUS, POSITION, EXTRA1, EXTRA2, EXTRA3 = 1, 2, 6, 10, 11, 12


@dataclass(frozen=True)
class Stream:
    """One stream the service reads: the message, its id, and ArduPilot's stream groups carrying it."""

    name: str
    message: str
    msgid: int
    data_streams: tuple[int, ...]
    why: str


#: the streams the service reads (docs/mavlink.md, "Asking for streams"); rates are settings
STREAMS: tuple[Stream, ...] = (
    Stream("battery", "BATTERY_STATUS", 147, (EXTRA3,), "packs: voltage, current, charge drawn"),
    Stream("position", "GLOBAL_POSITION_INT", 33, (POSITION,), "position, mission progress, message time"),
    Stream("airspeed", "VFR_HUD", 74, (EXTRA2,), "airspeed and climb: flight phase and shaft power"),
    Stream("esc", "ESC_TELEMETRY_1_TO_4", 11030, (EXTRA3, EXTRA1), "motors: current, rpm, temperature"),
    Stream("wind", "WIND", 168, (EXTRA3,), "wind (recorded in the tlog for fits and replays)"),
    Stream("ambient", "SCALED_PRESSURE", 29, (RAW_SENSORS,), "air temperature for the thermal models"),
    Stream("landed", "EXTENDED_SYS_STATE", 245, (EXTENDED_STATUS,), "landed or in air: flight phase of a multirotor"),
    Stream("mission", "MISSION_CURRENT", 42, (EXTENDED_STATUS,),
           "mission progress, and a changed mission on board (the service reads it again)"),
)
STREAM_NAMES = tuple(s.name for s in STREAMS)
#: default rates, Hz (``stream_rates_hz`` in the service's settings; 0 = never ask)
DEFAULT_RATES_HZ: dict[str, float] = {"battery": 2.0, "position": 2.0, "airspeed": 4.0, "esc": 2.0, "wind": 1.0,
                                      "ambient": 1.0, "landed": 1.0, "mission": 1.0}


@dataclass(frozen=True)
class Ask:
    """One request to send: SET_MESSAGE_INTERVAL for ``msgid`` at ``interval_us``, and, when
    ``data_streams`` is not empty, REQUEST_DATA_STREAM for each of those groups at ``rate_hz``."""

    stream: str
    msgid: int
    interval_us: int
    rate_hz: float
    data_streams: tuple[int, ...] = ()


@dataclass(frozen=True)
class StreamPolicy:
    rates_hz: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_RATES_HZ))
    #: seconds after the vehicle is identified before a stream that has not come is asked for
    grace_s: float = 2.0
    #: first wait before asking again, doubled after each ask up to ``max_retry_s``
    retry_s: float = 2.0
    max_retry_s: float = 60.0
    #: a stream silent this long (or three of its periods, asked or measured, if longer) has stopped
    stale_s: float = 5.0

    def __post_init__(self):
        unknown = set(self.rates_hz) - set(STREAM_NAMES)
        if unknown:
            raise ValueError(f"unknown stream(s) {sorted(unknown)}; the streams are {', '.join(STREAM_NAMES)}")
        bad = {k: v for k, v in self.rates_hz.items() if not (math.isfinite(v) and 0.0 <= v <= 50.0)}
        if bad:
            raise ValueError(f"stream rates must be 0 (never ask) to 50 Hz: {bad}")


@dataclass
class _State:
    first_s: float | None = None  # first arrival
    last_s: float | None = None  # latest arrival
    count: int = 0
    recent: list = field(default_factory=list)  # arrival times, for the measured rate
    asks: int = 0  # asks since it last came (or ever)
    asks_total: int = 0
    last_ask_s: float | None = None
    next_ask_s: float | None = None
    wait_s: float = 0.0


class StreamRequests:
    """Fed the tracked vehicle's messages (``on_message``), its HEARTBEAT (``on_vehicle``) and the
    COMMAND_ACKs of SET_MESSAGE_INTERVAL (``on_ack``); ``due(now)`` returns the asks to send now;
    ``report(now)`` says, per stream, what was asked for and what came (``/status.streams``)."""

    def __init__(self, policy: StreamPolicy | None = None):
        self.policy = policy or StreamPolicy()
        self.streams = {s.name: s for s in STREAMS}
        self._by_message = {s.message: s.name for s in STREAMS}
        self._state = {s.name: _State() for s in STREAMS}
        self.vehicle_since_s: float | None = None
        self.acks = {"accepted": 0, "refused": 0}
        self.last_refusal: int | None = None

    # --- what comes in -----------------------------------------------------------------------------

    def on_vehicle(self, now: float) -> None:
        """The tracked vehicle's autopilot HEARTBEAT (the first starts the grace period)."""
        if self.vehicle_since_s is None:
            self.vehicle_since_s = now

    def on_message(self, message: str, now: float) -> None:
        name = self._by_message.get(message)
        if name is None:
            return
        st = self._state[name]
        if st.first_s is None:
            st.first_s = now
        st.last_s = now
        st.count += 1
        st.recent.append(now)
        if len(st.recent) > 20:
            del st.recent[0]
        st.asks, st.next_ask_s = 0, None  # it came: the next silence is asked for from the start

    def on_ack(self, command: int, result: int) -> None:
        if command != SET_MESSAGE_INTERVAL:
            return
        if result == ACCEPTED:
            self.acks["accepted"] += 1
        else:
            self.acks["refused"] += 1
            self.last_refusal = int(result)

    # --- what to ask -------------------------------------------------------------------------------

    def rate_hz(self, name: str) -> float:
        return float(self.policy.rates_hz.get(name, 0.0))

    def _stale_after(self, name: str) -> float:
        """Silence after which a stream has stopped: ``stale_s``, or three periods of the rate asked
        for or of the rate it came at (a vehicle set to send it slowly is not taken for a silent one,
        so rates someone set are not overridden), whichever is longest."""
        periods = [1.0 / self.rate_hz(name)] if self.rate_hz(name) > 0 else []
        r = self._state[name].recent
        if len(r) >= 2:  # its mean period so far (from the second arrival on)
            periods.append((r[-1] - r[0]) / (len(r) - 1))
        return max([self.policy.stale_s] + [3.0 * p for p in periods])

    def receiving(self, name: str, now: float) -> bool:
        st = self._state[name]
        return st.last_s is not None and now - st.last_s <= self._stale_after(name)

    def _use_data_streams(self, st: _State) -> bool:
        refused = self.acks["refused"] > 0 and self.acks["accepted"] == 0
        ignored = st.asks >= 2 and self.acks["accepted"] == 0
        return refused or ignored

    def due(self, now: float) -> list[Ask]:
        """The asks to send now (each stream at most once per call)."""
        if self.vehicle_since_s is None or now - self.vehicle_since_s < self.policy.grace_s:
            return []
        out = []
        for name, stream in self.streams.items():
            rate = self.rate_hz(name)
            if rate <= 0 or self.receiving(name, now):
                continue
            st = self._state[name]
            if st.next_ask_s is not None and now < st.next_ask_s:
                continue
            st.wait_s = self.policy.retry_s if st.asks == 0 else min(self.policy.max_retry_s, st.wait_s * 2.0)
            groups = stream.data_streams if self._use_data_streams(st) else ()
            st.asks += 1
            st.asks_total += 1
            st.last_ask_s, st.next_ask_s = now, now + st.wait_s
            out.append(Ask(name, stream.msgid, int(round(1e6 / rate)), rate, groups))
        return out

    # --- what is said ------------------------------------------------------------------------------

    def measured_rate_hz(self, name: str) -> float | None:
        r = self._state[name].recent
        return round((len(r) - 1) / (r[-1] - r[0]), 2) if len(r) >= 3 and r[-1] > r[0] else None

    def report(self, now: float) -> dict:
        """Per stream: ``state`` (receiving | asked | waiting | stopped | not asked), the message, the
        rate asked for, the rate measured, asks sent, seconds since it last came; and the vehicle's
        answers to SET_MESSAGE_INTERVAL."""
        streams = {}
        for name, stream in self.streams.items():
            st, rate = self._state[name], self.rate_hz(name)
            if self.receiving(name, now):
                state = "receiving"
            elif rate <= 0:
                state = "not asked (rate 0)"
            elif st.asks == 0:
                state = "waiting" if st.last_s is None else "stopped"
            elif st.last_s is None:
                state = f"asked {st.asks} time(s), not come" + (" (the vehicle may not have it)" if st.asks >= 4 else "")
            else:
                state = f"stopped; asked again {st.asks} time(s)"
            streams[name] = {
                "message": stream.message, "state": state, "rate_hz_asked": rate if st.asks_total else None,
                "rate_hz_setting": rate, "rate_hz_measured": self.measured_rate_hz(name) if state == "receiving" else None,
                "asks": st.asks_total, "received": st.count,
                "last_s_ago": None if st.last_s is None else round(now - st.last_s, 1),
                "asked_s_ago": None if st.last_ask_s is None else round(now - st.last_ask_s, 1),
                "why": stream.why}
        return {"vehicle_identified": self.vehicle_since_s is not None, "streams": streams,
                "set_message_interval": {**self.acks, "last_refusal": self.last_refusal},
                "missing": sorted(n for n, s in streams.items() if s["state"] != "receiving"
                                  and self.rate_hz(n) > 0)}
