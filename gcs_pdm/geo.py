"""Local flat-earth geometry about a home point: the one place positions change frames.

Missions are flown within a few km of home, where an equirectangular projection about home is
well under a metre off; every module that turns MAVLink degrees into metres uses these.
"""
from __future__ import annotations

import math

EARTH_RADIUS_M = 6_371_000.0


def enu_from_geodetic(lat_deg: float, lon_deg: float, home_lat_deg: float, home_lon_deg: float) -> tuple[float, float]:
    """(east, north) metres of a point about home."""
    north = math.radians(lat_deg - home_lat_deg) * EARTH_RADIUS_M
    east = math.radians(lon_deg - home_lon_deg) * EARTH_RADIUS_M * math.cos(math.radians(home_lat_deg))
    return east, north


def geodetic_from_enu(east_m: float, north_m: float, home_lat_deg: float, home_lon_deg: float) -> tuple[float, float]:
    """(lat, lon) degrees of a point (east, north) metres from home."""
    lat = home_lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = home_lon_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(home_lat_deg))))
    return lat, lon
