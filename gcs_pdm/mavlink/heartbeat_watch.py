"""Whether the tracked vehicle's heartbeats look like one vehicle's.

On an unsigned link anyone can send a HEARTBEAT with the vehicle's system and component id. Alone,
such heartbeats would keep a silent vehicle "up" (the link's loss is judged by heartbeats). The
link therefore counts a heartbeat as the vehicle's life only while the vehicle's timed telemetry
is alive too (``Link.vehicle_silent_s``), and this watch notices heartbeats out of the vehicle's
pattern:

* ``duplicate``: two within ``MIN_INTERVAL_S`` of the vehicle's time with none of the vehicle's
  timed telemetry between them (autopilots send one a second: a second sender, or a link that
  duplicates packets). The interval is the wall interval times the vehicle's pace (message seconds
  per wall second over its last ``PACE_SAMPLES`` timed samples, never below 1): a simulator running
  60 times faster than real time sends its 1 Hz heartbeats 17 ms of wall time apart, and a timed
  sample it dropped (its seeded drop-outs) must not make two of them "duplicate" (the demo's false
  banner, issue 33). A sender can only raise the pace by moving the vehicle's message time, which
  the clock's rules and its ``RateWatch`` are there for. Only a heartbeat announcing the same state
  (custom mode, base mode, system status) as the one before counts: two commands in quick
  succession (a mode change, the mission's restart after an upload) are each acknowledged by a
  heartbeat of the new state;
* ``identity``: a field a vehicle never changes (MAV_TYPE, MAV_AUTOPILOT, mavlink_version) differs
  from the first heartbeat's;
* ``out_of_sequence``: its sequence number does not continue the id's previous packet (one sender
  numbers all its packets with one counter; gcs_pdm.mavlink.sequence);
* ``uncorroborated``: it arrives while the vehicle's timed telemetry has been silent for more than
  ``UNCORROBORATED_AFTER_S`` (a heartbeat without the vehicle's stream is not the vehicle).

``SUSPECT_COUNT`` of them within ``WINDOW_S`` (wall seconds) raise ``suspected``: a warning and a
degraded /health until the window passes. Only MAVLink signing proves who sent a heartbeat.
"""
from __future__ import annotations

import logging
import math
from collections import deque

log = logging.getLogger(__name__)

MIN_INTERVAL_S = 0.25
#: the vehicle's pace is measured over this many of its latest timed samples (about 2 s at 4 Hz)
PACE_SAMPLES = 8
UNCORROBORATED_AFTER_S = 3.0
SUSPECT_COUNT = 3
WINDOW_S = 60.0
KINDS = ("duplicate", "identity", "out_of_sequence", "uncorroborated")
#: HEARTBEAT's payload: custom_mode u32, then type, autopilot, base_mode, system_status, mavlink_version
_TYPE_AT, _AUTOPILOT_AT, _BASE_MODE_AT, _VERSION_AT = 4, 5, 6, 8


def _identity(payload: bytes) -> tuple[int, int, int]:
    p = bytes(payload).ljust(9, b"\0")  # MAVLink 2 drops trailing zero bytes
    return p[_TYPE_AT], p[_AUTOPILOT_AT], p[_VERSION_AT]


def _state(payload: bytes) -> bytes:
    """What a heartbeat announces: custom_mode, base_mode, system_status."""
    p = bytes(payload).ljust(9, b"\0")
    return p[0:_TYPE_AT] + p[_BASE_MODE_AT:_VERSION_AT]


class HeartbeatWatch:
    def __init__(self):
        self.counts = dict.fromkeys(KINDS, 0)
        self.heartbeats = 0
        self._identity: tuple[int, int, int] | None = None
        self._last_at: float | None = None
        self._last_timed_count: int | None = None
        self._last_state: bytes | None = None
        self._recent: deque[tuple[float, str]] = deque()
        self._warned = False
        #: (wall s, message s) of the vehicle's latest timed samples (``note_timed``)
        self._timed: deque[tuple[float, float]] = deque(maxlen=PACE_SAMPLES)

    def note_timed(self, at_s: float, message_time_s: float | None) -> None:
        """One of the vehicle's timed samples accepted at wall time ``at_s``, the vehicle's time then."""
        if message_time_s is not None:
            self._timed.append((at_s, message_time_s))

    def pace(self) -> float:
        """The vehicle's pace: the median over its latest timed samples of message seconds per wall
        second from one to the next (a median: a simulator sends several ticks in one burst, and its
        clock waits while the demo's service decides); 1 (real time) until there are two, and never
        below 1 (a stall is not a faster clock)."""
        t = list(self._timed)
        rates = sorted((b[1] - a[1]) / (b[0] - a[0]) if b[0] > a[0] else math.inf for a, b in zip(t, t[1:]))
        if not rates:
            return 1.0
        return max(1.0, rates[len(rates) // 2])

    def note(self, at_s: float, payload: bytes, seq: int, previous_seq: int | None,
             timed_silent_s: float | None, timed_count: int | None = None) -> list[str]:
        """One heartbeat of the tracked id received at wall time ``at_s``: the anomalies it shows.
        ``previous_seq``: the id's packet before it; ``timed_silent_s``: wall seconds since the
        vehicle's timed telemetry was last accepted (None: it never sent any); ``timed_count``: how
        many timed samples the vehicle clock has accepted so far (None: it has no time yet)."""
        self.heartbeats += 1
        found = []
        ident = _identity(payload)
        if self._identity is None:
            self._identity = ident
        elif ident != self._identity:
            found.append("identity")
        state = _state(payload)
        if (self._last_at is not None and (at_s - self._last_at) * self.pace() < MIN_INTERVAL_S
                and state == self._last_state and timed_count is not None
                and timed_count == self._last_timed_count):
            found.append("duplicate")
        if previous_seq is not None and not 1 <= (seq - previous_seq) % 256 <= 128:
            found.append("out_of_sequence")
        if timed_silent_s is not None and timed_silent_s > UNCORROBORATED_AFTER_S:
            found.append("uncorroborated")
        self._last_at = at_s
        self._last_state = state
        self._last_timed_count = timed_count
        for kind in found:
            self.counts[kind] += 1
            self._recent.append((at_s, kind))
        self._expire(at_s)
        if self.suspected(at_s) and not self._warned:
            self._warned = True
            log.warning("heartbeats of the vehicle's id out of its pattern: %s", self.reason(at_s))
        return found

    def _expire(self, now_s: float) -> None:
        while self._recent and now_s - self._recent[0][0] > WINDOW_S:
            self._recent.popleft()

    def suspected(self, now_s: float) -> bool:
        self._expire(now_s)
        return len(self._recent) >= SUSPECT_COUNT

    def reason(self, now_s: float) -> str:
        self._expire(now_s)
        kinds: dict[str, int] = {}
        for _, kind in self._recent:
            kinds[kind] = kinds.get(kind, 0) + 1
        what = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in kinds.items())
        return (f"{what} in the last {WINDOW_S:g} s: another sender may use the vehicle's ids "
                "(heartbeats count only with the vehicle's timed telemetry; sign the link)")

    def to_dict(self, now_s: float) -> dict:
        suspected = self.suspected(now_s)
        return {"heartbeats": self.heartbeats, "anomalies": dict(self.counts), "suspected": suspected,
                **({"reason": self.reason(now_s)} if suspected else {})}
