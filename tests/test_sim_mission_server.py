"""Vehicle side of the mission protocol, driven message by message (no sockets, explicit time)."""
from __future__ import annotations

import dataclasses

import pytest

from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.missions import MissionItem, as_sent, same_items
from gcs_pdm.sim.mission_server import MissionServer, ServerTimeouts
from gcs_pdm.sim.model import SimConfig, VehicleModel
from gcs_pdm.sim.routes import mission_from_enu

GCS = (255, 195)
OTHER_GCS = (255, 190)
MISSION = mission_from_enu([(500, 0, 80), (500, 500, 80)])
OLD = mission_from_enu([(-300, 0, 50)])


class Gcs:
    """Builds GCS messages with a source address, as pymavlink decodes them."""

    def __init__(self, src=GCS):
        self.mav = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])

    def _stamp(self, msg):
        msg.pack(self.mav)  # sets the header's source system/component
        return self.mav.decode(msg.get_msgbuf())

    def count(self, n, mission_type=0):
        return self._stamp(self.mav.mission_count_encode(1, 1, n, mission_type))

    def item(self, it: MissionItem):
        return self._stamp(self.mav.mission_item_int_encode(1, 1, it.seq, it.frame, it.command, it.current,
                                                            it.autocontinue, it.param1, it.param2, it.param3,
                                                            it.param4, it.x, it.y, it.z, it.mission_type))

    def request_list(self, mission_type=0):
        return self._stamp(self.mav.mission_request_list_encode(1, 1, mission_type))

    def request_int(self, seq):
        return self._stamp(self.mav.mission_request_int_encode(1, 1, seq, 0))

    def request(self, seq):
        return self._stamp(self.mav.mission_request_encode(1, 1, seq, 0))

    def ack(self, result):
        return self._stamp(self.mav.mission_ack_encode(1, 1, result, 0))

    def clear(self):
        return self._stamp(self.mav.mission_clear_all_encode(1, 1, 0))

    def set_current(self, seq):
        return self._stamp(self.mav.mission_set_current_encode(1, 1, seq))


def server(mission=OLD):
    model = VehicleModel(SimConfig(mission=tuple(mission), autostart=False))
    return MissionServer(model, timeouts=ServerTimeouts(item_s=0.25, retries=5)), model


def only(msgs, mtype):
    assert len(msgs) == 1 and msgs[0].get_type() == mtype, [m.get_type() for m in msgs]
    return msgs[0]


def upload(srv, gcs, items, t=0.0):
    req = only(srv.handle(gcs.count(len(items)), t), "MISSION_REQUEST_INT")
    for it in items:
        assert req.seq == it.seq and (req.target_system, req.target_component) == GCS
        out = srv.handle(gcs.item(it), t)
        req = out[0]
    return req


def test_upload_replaces_the_mission_and_acks_accepted():
    srv, model = server()
    ack = upload(srv, Gcs(), MISSION)
    assert ack.get_type() == "MISSION_ACK" and ack.type == mavlink2.MAV_MISSION_ACCEPTED
    assert same_items(model.mission, [as_sent(it) for it in MISSION])
    assert model.current_seq == 1


def test_lost_item_is_re_requested_and_the_upload_completes():
    srv, model = server()
    gcs = Gcs()
    srv.handle(gcs.count(len(MISSION)), 0.0)
    srv.handle(gcs.item(MISSION[0]), 0.01)  # request for 1 goes out; item 1 is "lost"
    assert srv.poll(0.2) == []  # not yet due
    again = only(srv.poll(0.3), "MISSION_REQUEST_INT")
    assert again.seq == 1
    # items out of sequence are ignored, not accepted
    assert srv.handle(gcs.item(MISSION[2]), 0.31) == []
    for it in MISSION[1:]:
        out = srv.handle(gcs.item(it), 0.32)
    assert out[0].get_type() == "MISSION_ACK" and out[0].type == mavlink2.MAV_MISSION_ACCEPTED
    assert len(model.mission) == len(MISSION) and srv.stats["rerequests"] == 1


def test_silent_gcs_gets_cancelled_and_the_old_mission_stays():
    srv, model = server()
    gcs = Gcs()
    srv.handle(gcs.count(len(MISSION)), 0.0)
    srv.handle(gcs.item(MISSION[0]), 0.0)
    t, out = 0.0, []
    for _ in range(5):
        t += 0.26
        assert only(srv.poll(t), "MISSION_REQUEST_INT").seq == 1
    t += 0.26
    ack = only(srv.poll(t), "MISSION_ACK")
    assert ack.type == mavlink2.MAV_MISSION_OPERATION_CANCELLED
    assert same_items(model.mission, OLD) and srv.upload is None


@pytest.mark.parametrize("change, result", [
    (dict(command=31000), mavlink2.MAV_MISSION_UNSUPPORTED),
    (dict(frame=1), mavlink2.MAV_MISSION_UNSUPPORTED_FRAME),
    (dict(x=950_000_000), mavlink2.MAV_MISSION_INVALID_PARAM5_X),
    (dict(y=-1_850_000_000), mavlink2.MAV_MISSION_INVALID_PARAM6_Y),
])
def test_an_item_the_vehicle_cannot_fly_is_refused_with_its_reason(change, result):
    srv, model = server()
    bad = list(MISSION)
    bad[2] = dataclasses.replace(bad[2], **change)
    ack = upload(srv, Gcs(), bad[:3])
    assert ack.get_type() == "MISSION_ACK" and ack.type == result
    assert same_items(model.mission, OLD)


def test_second_gcs_is_denied_while_an_upload_runs_and_count_zero_clears():
    srv, model = server()
    srv.handle(Gcs().count(3), 0.0)
    ack = only(srv.handle(Gcs(OTHER_GCS).count(2), 0.0), "MISSION_ACK")
    assert ack.type == mavlink2.MAV_MISSION_DENIED and (ack.target_system, ack.target_component) == OTHER_GCS
    # the same GCS restarting is fine; a count of 0 clears
    ack = only(srv.handle(Gcs().count(0), 0.1), "MISSION_ACK")
    assert ack.type == mavlink2.MAV_MISSION_ACCEPTED and model.mission == []
    assert only(srv.handle(Gcs().count(10_000), 0.2), "MISSION_ACK").type == mavlink2.MAV_MISSION_NO_SPACE


def test_gcs_cancel_aborts_the_upload():
    srv, model = server()
    gcs = Gcs()
    srv.handle(gcs.count(len(MISSION)), 0.0)
    srv.handle(gcs.ack(mavlink2.MAV_MISSION_OPERATION_CANCELLED), 0.0)
    assert srv.upload is None and srv.poll(5.0) == []
    assert same_items(model.mission, OLD)


def test_download_in_any_order_with_int_and_legacy_requests():
    srv, model = server(MISSION)
    gcs = Gcs()
    count = only(srv.handle(gcs.request_list(), 0.0), "MISSION_COUNT")
    assert count.count == len(MISSION)
    for seq in reversed(range(len(MISSION))):
        item = only(srv.handle(gcs.request_int(seq), 0.0), "MISSION_ITEM_INT")
        assert (item.seq, item.x, item.y, item.command) == (seq, MISSION[seq].x, MISSION[seq].y, MISSION[seq].command)
        assert item.current == (1 if seq == model.current_seq else 0)
    legacy = only(srv.handle(gcs.request(2), 0.0), "MISSION_ITEM")
    assert legacy.x == pytest.approx(MISSION[2].x / 1e7, abs=1e-6)
    bad = only(srv.handle(gcs.request_int(99), 0.0), "MISSION_ACK")
    assert bad.type == mavlink2.MAV_MISSION_INVALID_SEQUENCE
    # fence and rally lists are empty
    assert only(srv.handle(gcs.request_list(mavlink2.MAV_MISSION_TYPE_FENCE), 0.0), "MISSION_COUNT").count == 0


def test_clear_and_set_current():
    srv, model = server(MISSION)
    gcs = Gcs()
    assert srv.handle(gcs.set_current(3), 0.0) == []
    assert model.current_seq == 3
    events = model.take_events()
    assert [e.seq for e in events if e.kind == "current"][-1] == 3
    err = only(srv.handle(gcs.set_current(42), 0.0), "STATUSTEXT")
    assert err.severity <= mavlink2.MAV_SEVERITY_ERROR
    ack = only(srv.handle(gcs.clear(), 0.0), "MISSION_ACK")
    assert ack.type == mavlink2.MAV_MISSION_ACCEPTED and model.mission == []


def test_upload_in_flight_honours_a_current_flag_on_a_flown_item():
    srv, model = server(MISSION)
    model.config = dataclasses.replace(model.config, autostart=True)
    model.start_mission()
    while model.current_seq < 3:
        model.step()
    new = mission_from_enu([(-500, 0, 80), (-500, -500, 80), (0, -500, 80)])
    ack = upload(srv, Gcs(), new)
    assert ack.type == mavlink2.MAV_MISSION_ACCEPTED and model.current_seq == 3  # index kept
    flagged = [dataclasses.replace(it, current=1 if it.seq == 2 else 0) for it in new]
    upload(srv, Gcs(), flagged)
    assert model.current_seq == 2


def test_messages_for_other_vehicles_are_ignored():
    srv, model = server()
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=195)
    msg = mav.mission_count_encode(7, 1, 2, 0)
    msg.pack(mav)
    assert srv.handle(mav.decode(msg.get_msgbuf()), 0.0) == []


def test_commands_answer_with_acks_and_requested_messages():
    from gcs_pdm.sim.commands import CommandHandler
    from gcs_pdm.sim.telemetry import Telemetry

    model = VehicleModel(SimConfig(mission=tuple(MISSION), autostart=False))
    tel = Telemetry()
    handler = CommandHandler(model, tel)
    gcs = Gcs()

    def command(cmd, *params):
        p = list(params) + [0.0] * (7 - len(params))
        return handler.handle(gcs._stamp(gcs.mav.command_long_encode(1, 1, cmd, 0, *p)))

    ack, version = command(mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED and (ack.target_system, ack.target_component) == GCS
    assert version.capabilities & mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    ack, *batteries = command(mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS)
    assert [b.id for b in batteries] == [0, 1, 2, 3]
    (ack,) = command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_VFR_HUD, 100_000)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED and tel.rates["VFR_HUD"] == pytest.approx(10.0)
    (ack,) = command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED and model.armed
    (ack,) = command(mavlink2.MAV_CMD_DO_SET_MODE, 1, 11)
    assert model.mode == "RTL"
    ack, text = command(mavlink2.MAV_CMD_DO_SET_MODE, 1, 99)
    assert ack.result == mavlink2.MAV_RESULT_DENIED and text.get_type() == "STATUSTEXT"
    (ack,) = command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED and not model.armed  # on the ground: allowed
    (ack,) = command(42424)
    assert ack.result == mavlink2.MAV_RESULT_UNSUPPORTED
