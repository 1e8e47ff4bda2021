"""Mission items and mission files: builders, exact WPL / .plan round trips, clear errors."""
from __future__ import annotations

import json
import random
from decimal import Decimal

import pytest

from gcs_pdm.mavlink.mission_files import (MissionFileError, format_wpl, parse_wpl, read_plan, read_wpl,
                                           write_plan, write_wpl)
from gcs_pdm.missions import (MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_TAKEOFF, MissionItem,
                              deg_to_e7, land, renumber, return_to_launch, same_items, takeoff, waypoint)


def random_mission(n: int, seed: int = 1) -> list[MissionItem]:
    rng = random.Random(seed)
    items = [takeoff(rng.uniform(-89, 89), rng.uniform(-179, 179), 60.0)]
    for _ in range(n):
        items.append(waypoint(rng.uniform(-90, 90), rng.uniform(-180, 180), rng.uniform(0, 5000),
                              hold_s=rng.choice([0.0, 2.5]), acceptance_radius_m=rng.uniform(0, 50)))
    items.append(land(-33.8688197, 151.2092955))
    items.append(return_to_launch())
    # A non-positional item with raw integers in x/y (MAV_FRAME_MISSION) must survive too.
    items.append(MissionItem(0, 2, 177, 0, 1, 1.0, 3.0, 0.0, 0.0, -7, 123456789, 0.0))
    return renumber(items)


def test_builders_use_1e7_integers_and_nearest_rounding():
    wp = waypoint(47.1234567, -122.7654321, 100.0, seq=3)
    assert (wp.x, wp.y, wp.z, wp.seq, wp.command) == (471234567, -1227654321, 100.0, 3, 16)
    assert deg_to_e7(0.00000006) == 1 and deg_to_e7(-0.00000016) == -2 and deg_to_e7(8.5455938) == 85455938
    assert takeoff(1, 2, 30).command == MAV_CMD_NAV_TAKEOFF
    assert land(1, 2).command == MAV_CMD_NAV_LAND
    assert return_to_launch().command == MAV_CMD_NAV_RETURN_TO_LAUNCH
    items = renumber([waypoint(0, 0, 10), waypoint(1, 1, 10)])
    assert [i.seq for i in items] == [0, 1] and [i.current for i in items] == [1, 0]


def test_wpl_round_trip_is_exact(tmp_path):
    items = random_mission(300)
    path = tmp_path / "m.waypoints"
    write_wpl(path, items)
    back = read_wpl(path)
    assert same_items(items, back)
    # Coordinates are written from the integers, seven decimals, no float detour.
    second = path.read_text().splitlines()[2].split("\t")
    assert len(second[8].split(".")[1]) == 7
    assert Decimal(second[8]) * 10**7 == items[1].x


def test_wpl_extreme_coordinates_round_trip():
    extremes = [MissionItem(i, 6, 16, 0, 1, 0.0, 0.0, 0.0, 0.0, x, y, 1.0)
                for i, (x, y) in enumerate([(900000000, 1800000000), (-900000000, -1800000000), (1, -1), (0, 0),
                                            (-2**31, 2**31 - 1)])]
    assert same_items(extremes, parse_wpl(format_wpl(extremes)))


def test_plan_round_trip_is_exact(tmp_path):
    items = random_mission(300, seed=2)
    path = tmp_path / "m.plan"
    write_plan(path, items)
    doc = json.loads(path.read_text())
    assert doc["fileType"] == "Plan" and doc["mission"]["version"] == 2
    assert len(doc["mission"]["items"]) == len(items)
    assert same_items(items, read_plan(path))


def test_plan_written_by_qgc_reads(tmp_path):
    qgc = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
           "mission": {"version": 2, "items": [
               {"type": "SimpleItem", "autoContinue": True, "command": 22, "doJumpId": 1, "frame": 3,
                "params": [15, 0, 0, None, 47.3977419, 8.5455938, 50]},
               {"type": "SimpleItem", "autoContinue": True, "command": 16, "doJumpId": 2, "frame": 3,
                "params": [0, 0, 0, None, 47.3980000, 8.5460000, 60]}]}}
    path = tmp_path / "qgc.plan"
    path.write_text(json.dumps(qgc))
    items = read_plan(path)
    assert [(i.seq, i.command, i.x, i.y, i.z) for i in items] == [
        (0, 22, 473977419, 85455938, 50.0), (1, 16, 473980000, 85460000, 60.0)]


def test_bad_files_raise_clear_errors(tmp_path):
    bad = tmp_path / "bad.waypoints"
    bad.write_text("QGC WPL 110\n0\t1\t0\t16\n")
    with pytest.raises(MissionFileError, match=r"bad.waypoints:2: expected 12 columns"):
        read_wpl(bad)
    bad.write_text("not a mission\n")
    with pytest.raises(MissionFileError, match="first line"):
        read_wpl(bad)
    survey = tmp_path / "survey.plan"
    survey.write_text(json.dumps({"fileType": "Plan", "mission": {"items": [{"type": "ComplexItem"}]}}))
    with pytest.raises(MissionFileError, match="ComplexItem"):
        read_plan(survey)
