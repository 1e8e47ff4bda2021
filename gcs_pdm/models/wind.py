"""The wind triangle and the two ways a wind is written (pure; floats or numpy arrays).

A wind is kept as the velocity of the air, east and north in m/s (the direction it blows
*towards*), because that is what adds to the airspeed vector. Autopilots and forecasts say where it
blows *from* (ArduPilot's ``WIND.direction``, degrees clockwise from north); the conversions live
here so every user turns one into the other the same way.
"""
from __future__ import annotations

import math

import numpy as np

#: below this ground speed (m/s) a leg is not flyable: the wind holds the aircraft in place
MIN_GROUND_SPEED_MPS = 1.0


def wind_from_speed_direction(speed_mps: float, from_deg: float) -> tuple[float, float]:
    """(east, north) velocity of a wind of ``speed_mps`` blowing FROM ``from_deg`` (0 = north, clockwise)."""
    a = math.radians(from_deg)
    return -speed_mps * math.sin(a), -speed_mps * math.cos(a)


def speed_direction(east_mps: float, north_mps: float) -> tuple[float, float]:
    """(speed m/s, the direction it blows FROM in [0, 360) degrees) of the air velocity (east, north)."""
    speed = math.hypot(east_mps, north_mps)
    from_deg = math.degrees(math.atan2(-east_mps, -north_mps)) % 360.0 if speed > 0 else 0.0
    return speed, from_deg


def ground_speed(track_east: np.ndarray | float, track_north: np.ndarray | float, airspeed: np.ndarray | float,
                 wind_en: tuple[float, float]) -> np.ndarray:
    """Ground speed along the unit track (east, north) at ``airspeed`` in the wind ``wind_en``.

    The aircraft crabs so its ground track stays on the leg: the crosswind w_c takes
    sqrt(V² − w_c²) of the airspeed along the track and the wind adds its along-track part w_a:
    v_g = w_a + sqrt(V² − w_c²). Returns NaN where the leg cannot be flown (the crosswind exceeds the
    airspeed, or the ground speed is below ``MIN_GROUND_SPEED_MPS``)."""
    we, wn = wind_en
    te, tn = np.asarray(track_east, dtype=np.float64), np.asarray(track_north, dtype=np.float64)
    v = np.asarray(airspeed, dtype=np.float64)
    along = we * te + wn * tn
    cross = we * tn - wn * te
    rest = v * v - cross * cross
    with np.errstate(invalid="ignore"):
        vg = along + np.sqrt(np.where(rest >= 0.0, rest, np.nan))
    return np.where(vg >= MIN_GROUND_SPEED_MPS, vg, np.nan)


def wind_from_triangle(groundspeed_en: tuple[float, float], airspeed_mps: float, heading_deg: float) -> tuple[float, float]:
    """Wind (east, north) from the ground velocity minus the airspeed vector along the heading
    (no sideslip): the estimate when the autopilot sends none."""
    h = math.radians(heading_deg)
    return groundspeed_en[0] - airspeed_mps * math.sin(h), groundspeed_en[1] - airspeed_mps * math.cos(h)
