"""GET /missions/current numbers the mission's waypoints as routes and plans do (issue 33): the
objectives' numbers when they are loaded, else the first mission's waypoints in order, so the
console can label every waypoint before any plan exists."""
from __future__ import annotations

from types import SimpleNamespace

from fastapi.testclient import TestClient

from gcs_pdm import missions as M
from gcs_pdm.geo import geodetic_from_enu
from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.runtime import Service

HOME = (47.0, 8.0)


def _mission(*places):
    """home, takeoff, a waypoint per (east, north) place, land."""
    wps = [M.waypoint(*geodetic_from_enu(e, n, *HOME), 100.0) for e, n in places]
    return M.renumber([M.waypoint(*HOME, 0.0), M.takeoff(*HOME, 50.0), *wps, M.land(*HOME)])


def _service(tmp_path, items, catalogue=None) -> Service:
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="mission-numbers-Tk7q2"))
    svc.loop = SimpleNamespace(mission_items=items, mission_time_s=5.0,
                               executor=SimpleNamespace(catalogue=catalogue), stop=lambda: None)
    return svc


def test_without_objectives_the_waypoints_are_numbered_in_the_missions_order(tmp_path):
    items = _mission((0, 500), (500, 500), (500, 0))
    svc = _service(tmp_path, items)
    try:
        body = TestClient(create_app(svc)).get("/missions/current").json()
    finally:
        svc.close()
    # items 0 (home), 1 (takeoff) and 5 (land) are no waypoints; JSON keys are strings
    assert body["waypoints"] == {"2": 1, "3": 2, "4": 3}


def test_with_objectives_the_waypoints_carry_the_objectives_numbers(tmp_path):
    from gcs_pdm.service.decision import CatalogueWaypoint

    places = {5: (0, 500), 7: (500, 500), 9: (500, 0)}
    catalogue = [CatalogueWaypoint(n, *geodetic_from_enu(e, north, *HOME), 100.0, 10.0) for n, (e, north) in places.items()]
    items = _mission(places[9], places[5])  # a replanned mission: 9 then 5
    svc = _service(tmp_path, items, catalogue)
    try:
        body = TestClient(create_app(svc)).get("/missions/current").json()
    finally:
        svc.close()
    assert body["waypoints"] == {"2": 9, "3": 5}
