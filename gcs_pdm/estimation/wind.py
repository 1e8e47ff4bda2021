"""The wind the vehicle flies in: the autopilot's own estimate, else the wind triangle.

Pure core: frames in (message time), an estimate out. The autopilot's estimate (ArduPilot's
``WIND``, PX4's ``WIND_COV`` → :class:`gcs_pdm.frames.WindFrame`) is taken as it is while it keeps
coming; when none has been heard for ``AUTOPILOT_STALE_S`` the wind is estimated from the ground
velocity (``PositionFrame``) minus the airspeed vector along the heading (``AirdataFrame``), averaged
over ``TRIANGLE_TAU_S`` (a single triangle is off by the sideslip and the airspeed's noise; turns
average them out). Before either, the wind is unknown (None), never assumed calm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from gcs_pdm.frames import AirdataFrame, PositionFrame, WindFrame
from gcs_pdm.models.wind import speed_direction, wind_from_speed_direction, wind_from_triangle

#: an autopilot estimate older than this (message time) gives way to the triangle
AUTOPILOT_STALE_S = 10.0
#: averaging time constant of the autopilot's estimate, s: the planner flies legs of minutes and wants
#: the mean wind, while a 1 Hz estimate carries the gusts. As the triangle's: at 10 s a gust of 1.2 m/s
#: per component (sim's default at 8 m/s) left about one reading in six more than 1 m/s off the mean
#: wind; at 30 s about one in thirty (docs/notes/2026-11-27-issue31-audit.md)
AUTOPILOT_TAU_S = 30.0
#: averaging time constant of the triangle estimate, s
TRIANGLE_TAU_S = 30.0
#: a triangle needs an airspeed and a ground velocity at most this far apart in time, and flight
PAIR_WINDOW_S = 1.0
MIN_AIRSPEED_MPS = 8.0
#: the triangle is used once it has averaged this long (a few samples are not an estimate)
TRIANGLE_SETTLE_S = 10.0


@dataclass(frozen=True)
class WindEstimate:
    time_s: float
    east_mps: float           # the air's velocity (the direction it blows towards)
    north_mps: float
    source: str               # "autopilot" or "triangle"

    @property
    def speed_mps(self) -> float:
        return speed_direction(self.east_mps, self.north_mps)[0]

    @property
    def from_deg(self) -> float:
        return speed_direction(self.east_mps, self.north_mps)[1]

    @property
    def en(self) -> tuple[float, float]:
        return (self.east_mps, self.north_mps)

    def to_dict(self) -> dict:
        speed, from_deg = speed_direction(self.east_mps, self.north_mps)
        return {"speed_mps": round(speed, 2), "from_deg": round(from_deg, 1), "east_mps": round(self.east_mps, 2),
                "north_mps": round(self.north_mps, 2), "source": self.source, "time_s": self.time_s}


class WindEstimator:
    def __init__(self) -> None:
        self._autopilot: WindEstimate | None = None
        self._air: tuple[float, float, float] | None = None  # (time, airspeed, heading)
        self._ground: tuple[float, float, float] | None = None  # (time, ve, vn)
        self._tri: tuple[float, float, float, float] | None = None  # (time, east, north, seconds averaged)

    def consume(self, frame) -> None:
        if isinstance(frame, WindFrame):
            if frame.speed_mps is not None and frame.from_deg is not None and math.isfinite(frame.speed_mps):
                e, n = wind_from_speed_direction(frame.speed_mps, frame.from_deg)
                prev = self._autopilot
                if prev is not None and 0.0 <= frame.time_s - prev.time_s <= AUTOPILOT_STALE_S:
                    a = math.exp(-(frame.time_s - prev.time_s) / AUTOPILOT_TAU_S)
                    e, n = a * prev.east_mps + (1 - a) * e, a * prev.north_mps + (1 - a) * n
                self._autopilot = WindEstimate(frame.time_s, e, n, "autopilot")
        elif isinstance(frame, AirdataFrame):
            if frame.airspeed is not None and frame.heading_deg is not None:
                self._air = (frame.time_s, float(frame.airspeed), float(frame.heading_deg))
                self._triangle()
        elif isinstance(frame, PositionFrame):
            if frame.ve is not None and frame.vn is not None:
                self._ground = (frame.time_s, float(frame.ve), float(frame.vn))
                self._triangle()

    def _triangle(self) -> None:
        if self._air is None or self._ground is None:
            return
        ta, airspeed, heading = self._air
        tg, ve, vn = self._ground
        if abs(ta - tg) > PAIR_WINDOW_S or airspeed < MIN_AIRSPEED_MPS:
            return
        t = max(ta, tg)
        e, n = wind_from_triangle((ve, vn), airspeed, heading)
        if self._tri is None or t - self._tri[0] > 10 * TRIANGLE_TAU_S:
            self._tri = (t, e, n, 0.0)
            return
        dt = max(t - self._tri[0], 0.0)
        if dt == 0.0:
            return
        a = math.exp(-dt / TRIANGLE_TAU_S)
        t0, e0, n0, span = self._tri
        self._tri = (t, a * e0 + (1 - a) * e, a * n0 + (1 - a) * n, span + dt)

    def estimate(self, now_s: float | None = None) -> WindEstimate | None:
        """The autopilot's estimate while fresh, else the settled triangle, else None (unknown)."""
        ap = self._autopilot
        if ap is not None and (now_s is None or now_s - ap.time_s <= AUTOPILOT_STALE_S):
            return ap
        if self._tri is not None and self._tri[3] >= TRIANGLE_SETTLE_S:
            t, e, n, _ = self._tri
            if now_s is None or now_s - t <= AUTOPILOT_STALE_S:
                return WindEstimate(t, e, n, "triangle")
        return None
