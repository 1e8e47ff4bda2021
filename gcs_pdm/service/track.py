"""The vehicle's recent track, kept by the service so a reloaded console page still draws it.

A bounded ring of positions in message time: at most one point per ``interval_s`` (faster
telemetry is decimated), none older than ``window_s`` behind the newest. Positions that cannot be
a place (missing, non-finite, out of range, or (0, 0): no GPS fix) are skipped and counted. A
message clock that jumps back by more than ``RESTART_S`` is a new session (a vehicle reboot, a
replay started again): the old track no longer joins the new one, so it is cleared.

Not thread-safe by itself: ``LiveState`` holds it under its lock.
"""
from __future__ import annotations

import math
from collections import deque

#: a message clock going back by more than this starts a new track
RESTART_S = 5.0


class Track:
    def __init__(self, window_s: float = 7200.0, interval_s: float = 1.0):
        if not (window_s > 0 and interval_s > 0):
            raise ValueError(f"Track: window_s and interval_s must be > 0, got {window_s}, {interval_s}")
        self.window_s = float(window_s)
        self.interval_s = float(interval_s)
        # the window at the interval bounds the ring, whatever the clock does
        self._points: deque[tuple[float, float, float, float | None, float | None]] = deque(
            maxlen=int(math.ceil(window_s / interval_s)) + 1)
        self.skipped_invalid = 0
        self.restarts = 0

    def add(self, time_s: float, lat_deg, lon_deg, alt_m=None, relative_alt_m=None) -> bool:
        """Record a position at message time ``time_s``; False when skipped (invalid or decimated)."""
        if not _place(lat_deg, lon_deg) or time_s is None or not math.isfinite(time_s):
            self.skipped_invalid += 1
            return False
        pts = self._points
        if pts:
            last = pts[-1][0]
            if time_s < last - RESTART_S:
                pts.clear()
                self.restarts += 1
            elif time_s < last + self.interval_s:
                return False
        pts.append((float(time_s), float(lat_deg), float(lon_deg), _finite(alt_m), _finite(relative_alt_m)))
        while pts and pts[0][0] < time_s - self.window_s:
            pts.popleft()
        return True

    def points(self, since_s: float | None = None) -> list[list]:
        """``[time_s, lat_deg, lon_deg, alt_m, relative_alt_m]`` oldest first (after ``since_s`` if given)."""
        return [list(p) for p in self._points if since_s is None or p[0] > since_s]

    def to_dict(self, since_s: float | None = None) -> dict:
        return {"window_s": self.window_s, "interval_s": self.interval_s,
                "fields": ["time_s", "lat_deg", "lon_deg", "alt_m", "relative_alt_m"],
                "points": self.points(since_s), "skipped_invalid": self.skipped_invalid, "restarts": self.restarts}


def _place(lat, lon) -> bool:
    try:
        lat, lon = float(lat), float(lon)
    except (TypeError, ValueError):
        return False
    return (math.isfinite(lat) and math.isfinite(lon) and -90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0
            and not (lat == 0.0 and lon == 0.0))


def _finite(v) -> float | None:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None
