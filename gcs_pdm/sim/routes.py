"""Missions from local coordinates, in the ArduPilot layout the vehicle flies (pure).

seq 0 home, seq 1 NAV_TAKEOFF, then one NAV_WAYPOINT per point (with a DO_CHANGE_SPEED before it
when that point asks for another airspeed), last NAV_LAND at home.
"""
from __future__ import annotations

from typing import Sequence

from gcs_pdm import missions
from gcs_pdm.missions import MissionItem, renumber
from gcs_pdm.geo import geodetic_from_enu
from gcs_pdm.sim.model import MAV_CMD_DO_CHANGE_SPEED


def change_speed(airspeed_mps: float) -> MissionItem:
    return MissionItem(seq=0, frame=missions.MAV_FRAME_MISSION, command=MAV_CMD_DO_CHANGE_SPEED, current=0,
                       autocontinue=1, param1=0.0, param2=float(airspeed_mps), param3=-1.0, param4=0.0,
                       x=0, y=0, z=0.0)


def mission_from_enu(points: Sequence[tuple[float, ...]], *, home_lat_deg: float = 37.0870,
                     home_lon_deg: float = -76.3800, home_alt_m: float = 0.0, takeoff_alt_m: float = 60.0,
                     land: bool = True) -> list[MissionItem]:
    """``points`` are (east m, north m, alt m above home[, airspeed m/s]) about home."""
    items = [missions.waypoint(home_lat_deg, home_lon_deg, home_alt_m, frame=missions.MAV_FRAME_GLOBAL_INT),
             missions.takeoff(home_lat_deg, home_lon_deg, takeoff_alt_m)]
    speed = None
    for p in points:
        if len(p) not in (3, 4):
            raise ValueError(f"points: expected (east, north, alt[, airspeed]), got {p!r}")
        if len(p) == 4 and p[3] != speed:
            speed = float(p[3])
            items.append(change_speed(speed))
        lat, lon = geodetic_from_enu(float(p[0]), float(p[1]), home_lat_deg, home_lon_deg)
        items.append(missions.waypoint(lat, lon, float(p[2])))
    if land:
        items.append(missions.land(home_lat_deg, home_lon_deg, 0.0))
    return renumber(items)
