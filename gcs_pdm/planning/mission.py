"""The chosen route as a mission the vehicle can fly (``MISSION_ITEM_INT`` items, ArduPilot layout).

Layout:

  seq 0  home (NAV_WAYPOINT at the home position, absolute altitude) — ArduPilot keeps home at
         seq 0 and overwrites it on upload, so it must be there but is never flown;
  seq 1  NAV_TAKEOFF to the first waypoint's altitude;
  then   for each waypoint of the route, a DO_CHANGE_SPEED when the leg's airspeed differs from the
         previous one, then the NAV_WAYPOINT;
  last   DO_CHANGE_SPEED for the return if needed, then NAV_LAND at the landing site.

Replanning in flight: the new mission is uploaded whole (the protocol replaces the old one
atomically or leaves it untouched) and :attr:`MissionPlan.current_seq` names the item to make
current with ``MISSION_SET_CURRENT`` right after the upload — the first item of the new route
(its speed change if any), so an airborne vehicle never re-flies the take-off and heads straight
for the first chosen waypoint. Before take-off ``current_seq`` is 1 (the take-off).
"""
from __future__ import annotations

from dataclasses import dataclass

from gcs_pdm import missions
from gcs_pdm.missions import MissionItem
from gcs_pdm.planning.plan import Plan
from gcs_pdm.geo import geodetic_from_enu
from gcs_pdm.planning.scenario import Scenario

MAV_CMD_DO_CHANGE_SPEED = 178
SPEED_TYPE_AIRSPEED = 0.0


@dataclass(frozen=True)
class MissionPlan:
    items: list[MissionItem]
    current_seq: int          # the item to set current after upload
    waypoint_seq: dict[int, int]  # waypoint number -> seq of its NAV_WAYPOINT


def change_speed(airspeed_mps: float, *, seq: int = 0) -> MissionItem:
    """DO_CHANGE_SPEED to an airspeed, throttle unchanged (param3 = -1)."""
    return MissionItem(seq=seq, frame=missions.MAV_FRAME_MISSION, command=MAV_CMD_DO_CHANGE_SPEED, current=0,
                       autocontinue=1, param1=SPEED_TYPE_AIRSPEED, param2=float(airspeed_mps), param3=-1.0,
                       param4=0.0, x=0, y=0, z=0.0)


def plan_to_mission(scenario: Scenario, plan: Plan, *, airborne: bool = True, speed_items: bool = True) -> MissionPlan:
    """Mission items for ``plan`` over ``scenario`` (see the module docstring for the layout)."""
    home = scenario.home
    wps = scenario.waypoints
    items: list[MissionItem] = []
    home_item = missions.waypoint(home.lat_deg, home.lon_deg, home.ground_alt_m, frame=missions.MAV_FRAME_GLOBAL_INT)
    items.append(home_item)
    first_alt = wps[plan.route[0]].alt_m if plan.route else max(scenario.start.alt_m, 30.0)
    items.append(missions.takeoff(home.lat_deg, home.lon_deg, first_alt))
    first_new = None
    speed = None
    waypoint_seq: dict[int, int] = {}
    speeds = list(plan.leg_airspeed_mps) or [w.airspeed_mps for w in (wps[i] for i in plan.route)] + [
        scenario.return_airspeed_mps]
    for leg, i in enumerate(plan.route):
        w = wps[i]
        if speed_items and speeds[leg] != speed:
            items.append(change_speed(speeds[leg]))
            first_new = len(items) - 1 if first_new is None else first_new
            speed = speeds[leg]
        lat, lon = geodetic_from_enu(w.east_m, w.north_m, home.lat_deg, home.lon_deg)
        items.append(missions.waypoint(lat, lon, w.alt_m))
        waypoint_seq[w.number] = len(items) - 1
        first_new = len(items) - 1 if first_new is None else first_new
    if speed_items and speeds[len(plan.route)] != speed:
        items.append(change_speed(speeds[len(plan.route)]))
        first_new = len(items) - 1 if first_new is None else first_new
    lat, lon = geodetic_from_enu(home.landing_east_m, home.landing_north_m, home.lat_deg, home.lon_deg)
    items.append(missions.land(lat, lon, 0.0))
    first_new = len(items) - 1 if first_new is None else first_new
    items = missions.renumber(items)
    current = first_new if airborne else 1
    items = [it if it.seq != current else _current(it) for it in (_clear(i) for i in items)]
    return MissionPlan(items=items, current_seq=current, waypoint_seq=waypoint_seq)


def _clear(item: MissionItem) -> MissionItem:
    from dataclasses import replace

    return replace(item, current=0)


def _current(item: MissionItem) -> MissionItem:
    from dataclasses import replace

    return replace(item, current=1)
