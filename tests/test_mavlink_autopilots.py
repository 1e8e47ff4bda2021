"""Comparing a mission read back from a vehicle with the one uploaded, by meaning, per autopilot."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import pytest

from gcs_pdm import missions as M
from gcs_pdm.mavlink.autopilots import (
    ARDUPILOT_COPTER, ARDUPILOT_PLANE, GENERIC, PX4, MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4,
    missions_equivalent, rules_for,
)
from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.mavlink.mission_client import MissionClient
from gcs_pdm.sim.model import SimConfig
from gcs_pdm.sim.vehicle import SimulatedVehicle

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_peers import free_udp_port  # noqa: E402

HOME = (-35.363261, 149.165230)
SENT = M.renumber([
    M.waypoint(*HOME, 0.0),  # item 0: home on ArduPilot
    M.takeoff(-35.3620, 149.1652, 40.0),
    M.waypoint(-35.3600, 149.1660, 80.0),
    M.waypoint(-35.3610, 149.1680, 80.0),
    M.land(-35.3632, 149.1652, 0.0),
    M.return_to_launch(),
])


def back(items=SENT):
    """The items as they come off the wire (float32 params), current flag as the vehicle sets it."""
    return [M.as_sent(i) for i in items]


def edit(items, seq, **change):
    out = list(items)
    out[seq] = dataclasses.replace(out[seq], **change)
    return out


def test_rules_follow_heartbeat_autopilot_and_type():
    assert rules_for(MAV_AUTOPILOT_ARDUPILOTMEGA, 1) is ARDUPILOT_PLANE
    assert rules_for(MAV_AUTOPILOT_ARDUPILOTMEGA, 2) is ARDUPILOT_COPTER  # quadrotor
    assert rules_for(MAV_AUTOPILOT_PX4, 1) is PX4
    assert rules_for(8) is GENERIC and rules_for(None) is GENERIC


@pytest.mark.parametrize("rules", [ARDUPILOT_PLANE, ARDUPILOT_COPTER, PX4, GENERIC])
def test_a_verbatim_read_back_is_equivalent_under_every_rule_set(rules):
    assert missions_equivalent(SENT, back(), rules).equivalent


@pytest.mark.parametrize("sent_frame, back_frame", [(6, 3), (5, 0), (11, 10)])
def test_int_and_float_frame_variants_are_the_same_frame(sent_frame, back_frame):
    sent = edit(SENT, 2, frame=sent_frame)
    for rules in (ARDUPILOT_PLANE, PX4, GENERIC):
        assert missions_equivalent(sent, edit(back(), 2, frame=back_frame), rules)


def test_ardupilot_reports_frame_0_for_a_command_without_location():
    assert SENT[5].frame == M.MAV_FRAME_MISSION
    assert missions_equivalent(SENT, edit(back(), 5, frame=0), ARDUPILOT_PLANE)
    assert not missions_equivalent(SENT, edit(back(), 5, frame=0), PX4)  # PX4 keeps frame 2


def test_relative_and_absolute_altitude_frames_differ():
    result = missions_equivalent(SENT, edit(back(), 2, frame=0), ARDUPILOT_PLANE)
    assert [(d.seq, d.field) for d in result.differences] == [(2, "frame")]


def test_ardupilot_reads_a_nan_param_back_as_0_but_generic_does_not():
    assert SENT[2].param4 != SENT[2].param4
    assert missions_equivalent(SENT, edit(back(), 2, param4=0.0), ARDUPILOT_PLANE)
    assert missions_equivalent(SENT, edit(back(), 1, param4=0.0), ARDUPILOT_COPTER)
    assert not missions_equivalent(SENT, edit(back(), 2, param4=0.0), GENERIC)


def test_ardupilot_nav_land_param4_reads_back_1():
    assert missions_equivalent(SENT, edit(back(), 4, param4=1.0), ARDUPILOT_PLANE)
    assert not missions_equivalent(SENT, edit(back(), 4, param4=1.0), GENERIC)
    # a negative param4 (yaw direction) is kept as -1, so 1 would be a real change
    sent = edit(SENT, 4, param4=-30.0)
    assert missions_equivalent(sent, edit(back(), 4, param4=-1.0), ARDUPILOT_PLANE)
    assert not missions_equivalent(sent, edit(back(), 4, param4=1.0), ARDUPILOT_PLANE)


def test_ardupilot_stores_takeoff_pitch_in_whole_degrees_and_plane_waypoint_radius_in_a_byte():
    sent = edit(edit(SENT, 1, param1=15.7), 2, param2=300.0)
    assert missions_equivalent(sent, edit(edit(back(), 1, param1=15.0), 2, param2=255.0), ARDUPILOT_PLANE)
    result = missions_equivalent(sent[:2] + SENT[2:], edit(back(), 1, param1=12.0), ARDUPILOT_PLANE)
    assert [(d.seq, d.field) for d in result.differences] == [(1, "param1")]


def test_ardupilot_drops_params_its_command_does_not_use():
    sent = edit(SENT, 2, param1=5.0)  # hold time: Plane does not store it, Copter does
    assert missions_equivalent(sent, edit(back(), 2, param1=0.0), ARDUPILOT_PLANE)
    assert not missions_equivalent(sent, edit(back(), 2, param1=0.0), ARDUPILOT_COPTER)


def test_ardupilot_always_reads_autocontinue_1():
    sent = edit(SENT, 3, autocontinue=0)
    assert missions_equivalent(sent, edit(back(), 3, autocontinue=1), ARDUPILOT_PLANE)
    assert not missions_equivalent(sent, edit(back(), 3, autocontinue=1), PX4)


def test_altitude_within_the_autopilots_storage_step():
    sent = edit(SENT, 2, z=80.004)
    assert missions_equivalent(sent, edit(back(), 2, z=80.0), ARDUPILOT_PLANE)  # whole centimetres
    assert not missions_equivalent(sent, edit(back(), 2, z=80.0), PX4)  # float: 4 mm is a change
    result = missions_equivalent(SENT, edit(back(), 2, z=80.5), ARDUPILOT_PLANE)
    assert [(d.seq, d.field) for d in result.differences] == [(2, "z")]


def test_coordinates_within_one_integer_step():
    assert missions_equivalent(SENT, edit(back(), 3, x=SENT[3].x + 1), PX4)
    result = missions_equivalent(SENT, edit(back(), 3, y=SENT[3].y + 900), PX4)  # ~9 m
    assert [(d.seq, d.field, d.note) for d in result.differences] == [(3, "y", "moved")]


def test_px4_wraps_yaw_to_0_360_and_keeps_nan_yaw():
    sent = edit(SENT, 2, param4=-90.0)
    assert missions_equivalent(sent, edit(back(), 2, param4=270.0), PX4)
    assert missions_equivalent(SENT, back(), PX4)  # NaN yaw stays NaN
    assert not missions_equivalent(SENT, edit(back(), 2, param4=0.0), PX4)


def test_item_0_is_home_on_ardupilot_but_compared_on_px4():
    home = dataclasses.replace(back()[0], x=SENT[0].x + 5000, z=584.0)
    assert missions_equivalent(SENT, [home] + back()[1:], ARDUPILOT_PLANE)
    assert not missions_equivalent(SENT, [home] + back()[1:], PX4)


def test_missing_extra_reordered_and_changed_items_are_named():
    missing = missions_equivalent(SENT, back()[:-1], ARDUPILOT_PLANE)
    assert [(d.seq, d.field, d.note) for d in missing.differences] == [(5, "item", "missing on the vehicle")]
    extra = missions_equivalent(SENT, back() + [dataclasses.replace(back()[2], seq=6)], ARDUPILOT_PLANE)
    assert [(d.seq, d.note) for d in extra.differences] == [(6, "extra on the vehicle")]
    b = back()
    swapped = b[:2] + [dataclasses.replace(b[3], seq=2), dataclasses.replace(b[2], seq=3)] + b[4:]
    reordered = missions_equivalent(SENT, swapped, ARDUPILOT_PLANE)
    assert [(d.seq, d.note) for d in reordered.differences] == [(2, "reordered"), (3, "reordered")]
    changed = missions_equivalent(SENT, edit(back(), 4, command=M.MAV_CMD_NAV_WAYPOINT), ARDUPILOT_PLANE)
    assert [(d.seq, d.field) for d in changed.differences] == [(4, "command")]
    assert "item 4 command" in changed.summary()


def test_the_issues_arduplane_read_back_is_confirmed():
    """The read-back the issue's ArduPlane produced (frames 6->3, 2->0, NaN->0, LAND param4->1, home)."""
    b = back()
    observed = [dataclasses.replace(b[0], x=-353632610, y=1491652300, z=584.07)]
    for item in b[1:]:
        frame = {6: 3, 2: 0}[item.frame]
        params = [0.0 if p != p else p for p in (item.param1, item.param2, item.param3, item.param4)]
        if item.command == M.MAV_CMD_NAV_LAND:
            params[3] = 1.0
        observed.append(dataclasses.replace(item, frame=frame, param1=params[0], param2=params[1],
                                            param3=params[2], param4=params[3]))
    assert missions_equivalent(SENT, observed, MAV_AUTOPILOT_ARDUPILOTMEGA).equivalent


def _fly_upload_and_read_back(items):
    port = free_udp_port()
    with Link(LinkConfig(url=f"udpin:127.0.0.1:{port}")) as link:
        vehicle = SimulatedVehicle(SimConfig(seed=3, autostart=False), f"udpout:127.0.0.1:{port}", speedup=1.0)
        vehicle.core.missions.store_like_arduplane = True
        with vehicle:
            link.wait_for_vehicle(10)
            client = MissionClient(link)
            client.upload(items)
            read_back = client.download()
    return read_back


def test_upload_to_a_vehicle_that_normalises_like_arduplane_is_confirmed_and_a_moved_item_is_not():
    read_back = _fly_upload_and_read_back(SENT)
    # the vehicle really normalised: the byte-level comparison would call this a mismatch
    assert read_back[2].frame == 3 and read_back[4].param4 == 1.0 and read_back[2].param4 == 0.0
    assert not M.same_items([M.as_sent(i) for i in SENT[1:]], [dataclasses.replace(i, current=0)
                                                                 for i in read_back[1:]])
    status = "confirmed" if missions_equivalent(SENT, read_back, MAV_AUTOPILOT_ARDUPILOTMEGA) else "upload_mismatch"
    assert status == "confirmed"
    # the plan the service thinks it uploaded had item 3 elsewhere: a genuine difference
    planned = edit(SENT, 3, x=SENT[3].x + 2000)
    result = missions_equivalent(planned, read_back, MAV_AUTOPILOT_ARDUPILOTMEGA)
    status = "confirmed" if result else "upload_mismatch"
    assert status == "upload_mismatch"
    assert [(d.seq, d.field) for d in result.differences] == [(3, "x")]
