"""Where a flight begins and ends, from message time and the armed flag alone (pure).

A flight begins at arming, or at a vehicle reboot (message time going back: the autopilot's clock
restarted, so whatever the previous flight knew is about another power-up). It ends at disarm, at
such a reboot, or when the vehicle has been silent for longer than ``link_lost_end_s`` of message
time (the next message after the silence closes it at its last heard time, and a vehicle heard
armed again then begins a new one). A service restart does not end a flight by itself: the
vehicle's next message decides (same clock and still armed: the same flight goes on).
"""
from __future__ import annotations

from dataclasses import dataclass

#: message time going back by more than this is a reboot, not jitter between two links' stamps
REBOOT_BACKSTEP_S = 2.0


@dataclass(frozen=True)
class Boundary:
    """One edge: ``kind`` "begin" or "end", at message time ``time_s``, and why."""
    kind: str
    time_s: float
    reason: str


class FlightBoundaries:
    """Fed each message's time and the latest armed flag (None: not heard); answers the boundaries
    it crosses. ``open_until_s``: a flight already open (restored from the store) last heard then."""

    def __init__(self, link_lost_end_s: float = 300.0, open_until_s: float | None = None):
        self.link_lost_end_s = float(link_lost_end_s)
        self.in_flight = open_until_s is not None
        self.last_time_s: float | None = open_until_s
        self.armed: bool | None = None

    def observe(self, time_s: float, armed: bool | None) -> list[Boundary]:
        out: list[Boundary] = []
        last = self.last_time_s
        if last is not None and time_s < last - REBOOT_BACKSTEP_S:
            if self.in_flight:
                out.append(Boundary("end", last, f"vehicle reboot (message time went back from {last:.1f} s "
                                                 f"to {time_s:.1f} s)"))
                self.in_flight = False
            self.armed = None  # a rebooted vehicle's armed state is news
            if armed:
                out.append(Boundary("begin", time_s, "vehicle reboot (message time went back)"))
                self.in_flight = True
        elif last is not None and time_s - last > self.link_lost_end_s and self.in_flight:
            out.append(Boundary("end", last, f"link lost for {time_s - last:.0f} s "
                                             f"(longer than {self.link_lost_end_s:g} s)"))
            self.in_flight = False
            if armed:
                out.append(Boundary("begin", time_s, "heard armed after the link was lost"))
                self.in_flight = True
        if not out:
            if armed and not self.in_flight:
                out.append(Boundary("begin", time_s, "armed" if self.armed is False else "heard armed"))
                self.in_flight = True
            elif armed is False and self.in_flight:
                out.append(Boundary("end", time_s, "disarmed"))
                self.in_flight = False
        self.armed = armed
        rebooted = last is not None and time_s < last - REBOOT_BACKSTEP_S
        # after a reboot the new clock counts; otherwise the newest time (two links' stamps jitter)
        self.last_time_s = time_s if last is None or rebooted else max(last, time_s)
        return out


def split_flights(time_s, armed, link_lost_end_s: float = 300.0) -> list[tuple[int, int, str, str]]:
    """A log's flights as index ranges: ``(first, last + 1, begin reason, end reason)`` over samples
    with message times ``time_s`` and armed flags ``armed`` (bool per sample); a flight still open
    at the end of the log ends with it ("end of log")."""
    fb = FlightBoundaries(link_lost_end_s)
    out, start, why = [], None, ""
    for k, (t, a) in enumerate(zip(time_s, armed)):
        for b in fb.observe(float(t), bool(a)):
            if b.kind == "end" and start is not None:
                out.append((start, k, why, b.reason))
                start = None
            elif b.kind == "begin":
                start, why = k, b.reason
    if start is not None:
        out.append((start, len(time_s), why, "end of log"))
    return out
