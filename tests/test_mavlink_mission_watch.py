"""MissionWatcher: when to (re)read the vehicle's mission, from messages and message time alone."""
from __future__ import annotations

from types import SimpleNamespace

from gcs_pdm.mavlink.mission_watch import MissionWatcher

VEHICLE = (1, 1)
US = (255, 190)
OTHER_GCS = 254


def msg(mtype, src=VEHICLE, **fields):
    return SimpleNamespace(get_type=lambda: mtype, get_srcSystem=lambda: src[0], get_srcComponent=lambda: src[1],
                           **fields)


def heartbeat(autopilot=3):
    return msg("HEARTBEAT", autopilot=autopilot, type=1)


def home(lat=-353632610, lon=1491652300):
    return msg("HOME_POSITION", latitude=lat, longitude=lon)


def current(seq=1, total=6, **extra):
    return msg("MISSION_CURRENT", seq=seq, total=total, **extra)


def watcher():
    w = MissionWatcher(*US, empty_retry_s=3.0, failed_retry_s=2.0)
    w.on_message(heartbeat(), 0.0)
    return w


def read(w, t, count):
    assert w.due(t) is not None
    w.read_started(t)
    w.read_done(count, t)


def test_first_heartbeat_makes_a_read_due_and_a_gcs_heartbeat_does_not():
    w = MissionWatcher(*US)
    w.on_message(msg("HEARTBEAT", src=(255, 0), autopilot=8, type=6), 0.0)  # a GCS: MAV_AUTOPILOT_INVALID
    assert w.due(0.0) is None
    w.on_message(heartbeat(), 0.5)
    assert w.due(0.5).reason == "vehicle first heard" and w.autopilot == 3 and w.vehicle_address == VEHICLE


def test_an_empty_read_before_home_is_retried_and_home_makes_a_read_due():
    w = watcher()
    read(w, 1.0, 0)  # ArduPilot before home: 0 items
    assert w.due(2.0) is None  # not hammering the vehicle
    assert w.due(4.1).reason == "empty mission read before home was set"
    w.read_started(4.1)
    w.read_done(0, 4.1)
    w.on_message(home(), 5.0)
    due = w.due(5.0)
    assert due is not None and due.reason == "home set"  # at once, not after the retry delay
    w.read_started(5.0)
    w.read_done(6, 5.2)
    assert w.due(60.0) is None  # a mission after home: nothing more to do
    w.on_message(home(), 70.0)  # the same home again: no read
    assert w.due(70.0) is None
    w.on_message(home(lat=-353632610 + 10_000), 80.0)  # ~110 m: a new home
    assert w.due(80.0).reason == "home moved"


def test_home_position_from_another_system_is_ignored():
    w = watcher()
    read(w, 0.5, 3)
    w.on_message(home(), 1.0)
    w.on_message(msg("HOME_POSITION", src=(2, 1), latitude=1, longitude=1), 1.0)
    read(w, 1.0, 3)
    assert w.home == (-353632610, 1491652300)


def test_a_change_of_mission_id_or_total_makes_a_read_due():
    w = watcher()
    read(w, 0.5, 6)
    w.on_message(current(total=6, mission_id=1234), 1.0)
    assert w.due(1.0) is None  # the first id is the baseline
    w.on_message(current(total=6, mission_id=1234), 2.0)
    assert w.due(2.0) is None
    w.on_message(current(total=6, mission_id=999), 3.0)
    assert w.due(3.0).reason == "mission id changed"
    read(w, 3.0, 6)
    w.on_message(current(total=8), 4.0)  # an autopilot without mission_id: the total tells
    assert w.due(4.0).reason == "mission item total changed"


def test_an_accepted_upload_by_another_gcs_makes_a_read_due_but_ours_does_not():
    w = watcher()
    read(w, 0.5, 6)
    w.on_message(msg("MISSION_ACK", target_system=US[0], target_component=US[1], type=0, mission_type=0), 1.0)
    assert w.due(1.0) is None
    w.on_message(msg("MISSION_ACK", target_system=OTHER_GCS, target_component=190, type=0, mission_type=2), 1.5)
    assert w.due(1.5) is None  # a rally list, not the mission
    w.on_message(msg("MISSION_ACK", target_system=OTHER_GCS, target_component=190, type=0, mission_type=0), 2.0)
    assert w.due(2.0).reason == f"upload by system {OTHER_GCS} accepted"


def test_mission_changed_from_someone_else_and_a_different_count_make_a_read_due():
    w = watcher()
    read(w, 0.5, 6)
    w.on_message(msg("MISSION_CHANGED", src=VEHICLE, mission_type=0, origin_sysid=US[0], origin_compid=US[1]), 1.0)
    assert w.due(1.0) is None
    w.on_message(msg("MISSION_CHANGED", mission_type=0, origin_sysid=OTHER_GCS, origin_compid=190), 1.0)
    assert w.due(1.0).reason == "vehicle reports its mission changed"
    read(w, 1.0, 6)
    w.on_message(msg("MISSION_COUNT", target_system=OTHER_GCS, target_component=190, count=6, mission_type=0), 2.0)
    assert w.due(2.0) is None
    w.on_message(msg("MISSION_COUNT", target_system=OTHER_GCS, target_component=190, count=9, mission_type=0), 3.0)
    assert w.due(3.0).reason == "vehicle announced a different item count"


def test_a_change_during_a_read_makes_another_read_due_after_it():
    w = watcher()
    w.read_started(0.1)
    w.on_message(current(total=6, mission_id=1), 0.2)
    w.on_message(current(total=6, mission_id=2), 0.3)
    assert w.due(0.3) is None  # one read at a time
    w.read_done(6, 0.4)
    assert w.due(0.4).reason == "mission id changed"


def test_failed_reads_back_off():
    w = watcher()
    w.read_started(0.0)
    w.read_failed(1.0)
    assert w.due(2.5) is None and w.due(3.0).reason == "previous read failed"
    w.read_started(3.0)
    w.read_failed(3.5)
    assert w.due(6.0) is None and w.due(7.5) is not None  # 4 s after the second failure


def test_our_own_upload_is_adopted_without_a_read():
    w = watcher()
    read(w, 0.5, 6)
    w.on_message(current(total=6, mission_id=1), 1.0)
    w.uploaded(4)
    w.on_message(current(total=4, mission_id=2), 2.0)
    assert w.due(2.0) is None and w.count == 4 and w.mission_id == 2
    w.on_message(current(total=4, mission_id=3), 3.0)  # then someone else's
    assert w.due(3.0).reason == "mission id changed"
