"""Mission protocol against MAVSDK's MissionRawServer (C++), directly and through 20 % loss.

MAVSDK plays the vehicle: an implementation we did not write. The relay drops a seeded 20 % of
datagrams in each direction. Uploaded items are compared with what MAVSDK reports it received,
downloads with what was uploaded (params and z as float32, as on the wire).
"""
from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import pytest

from gcs_pdm.mavlink.connection import DEFAULT_SOURCE_SYSTEM as OUR_SYSTEM, Link, LinkConfig
from gcs_pdm.mavlink.dialect import mavlink2, mavutil
from gcs_pdm.mavlink.mission_client import MissionClient, MissionError, MissionRejected, MissionTimeouts
from gcs_pdm.missions import MissionItem, as_sent, renumber, same_items, takeoff, waypoint

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_peers import LossyRelay, MavsdkVehicle, free_udp_port  # noqa: E402

mavsdk = pytest.importorskip("mavsdk", reason="the mavsdk package (test extra) provides MissionRawServer")


def mission(n: int, seed: int = 0) -> list[MissionItem]:
    items = [takeoff(-35.3632621, 149.1652374, 40.0)]
    items += [waypoint(-35.3632621 + 1e-4 * i + 1e-7 * seed, 149.1652374 - 7e-5 * i, 50.0 + (i % 7) * 0.3,
                       acceptance_radius_m=0.1 * i) for i in range(1, n)]
    return renumber(items[:n])


SUCCESS = 1  # MissionRawServerResult.SUCCESS; re-sent MISSION_COUNTs also report BUSY


def server_items(vehicle: MavsdkVehicle, since: int) -> list[MissionItem] | None:
    accepted = [raw for result, raw in vehicle.incoming[since:] if int(result) == SUCCESS]
    if not accepted:
        return None
    raw = accepted[-1]
    return [MissionItem(i.seq, i.frame, i.command, i.current, i.autocontinue, i.param1, i.param2, i.param3,
                        i.param4, i.x, i.y, i.z, i.mission_type) for i in raw]


def eventually(condition, timeout: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return bool(condition())


@pytest.fixture(scope="module")
def vehicle():
    v = MavsdkVehicle(free_udp_port()).start()
    yield v
    v.close()


@pytest.fixture(scope="module", params=[0.0, 0.2], ids=["lossless", "loss20"])
def client(request, vehicle):
    relay = LossyRelay(vehicle.port, drop=request.param, seed=20260522).start()
    link = Link(LinkConfig(url=f"udpout:127.0.0.1:{relay.listen_port}",
                           source_component=195 if request.param == 0 else 196)).start()
    link.wait_for_vehicle(timeout=15)
    yield MissionClient(link), relay
    link.close()
    relay.close()


@pytest.mark.slow
@pytest.mark.parametrize("n", [1, 20, 500])
def test_upload_and_download(client, vehicle, n):
    mc, relay = client
    items = mission(n, seed=n)
    before = len(vehicle.incoming)
    mc.upload(items)
    # MAVSDK's callbacks run on its own thread.
    assert eventually(lambda: server_items(vehicle, before) is not None)
    expected = [as_sent(i) for i in items]
    assert same_items(server_items(vehicle, before), expected)
    downloaded = mc.download()
    assert same_items(downloaded, expected)
    if relay.drop:
        assert sum(relay.dropped) > 0


def test_set_current_and_clear(client, vehicle):
    mc, _ = client
    mc.upload(mission(5))
    mc.set_current(3)
    assert eventually(lambda: vehicle.current and vehicle.current[-1] == 3)
    cleared = len(vehicle.cleared)
    mc.clear()
    assert eventually(lambda: len(vehicle.cleared) >= cleared + 1)  # a re-sent clear clears again
    assert mc.download() == []


# --- a scripted vehicle for behaviours MAVSDK does not show ------------------------------------

class ScriptedVehicle:
    """A pymavlink vehicle: answers uploads with legacy MISSION_REQUEST and a chosen final ACK."""

    def __init__(self, final_result: int | None = mavlink2.MAV_MISSION_ACCEPTED, legacy: bool = True,
                 crosstalk: bool = False):
        self.port = free_udp_port()
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=1, source_component=1,
                                               dialect="ardupilotmega")
        self.final_result = final_result
        self.legacy = legacy
        # Mission traffic for another GCS (QGroundControl, 255/190) on the same link, as a router
        # forwards it, plus an early ACCEPTED to us: none of it may end our upload.
        self.crosstalk = crosstalk
        self.received: list = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        mav = self.conn.mav
        count = None
        next_hb = 0.0
        while not self._stop.is_set():
            if time.monotonic() > next_hb:
                next_hb = time.monotonic() + 0.2
                try:
                    mav.heartbeat_send(1, 3, 0x80, 0, 4)
                except OSError:
                    pass
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            mtype = msg.get_type()
            if mtype == "MISSION_COUNT":
                count, self.received = msg.count, []
                self._request(0)
            elif mtype == "MISSION_ITEM_INT" and count is not None and msg.seq == len(self.received):
                self.received.append(msg)
                if len(self.received) < count:
                    self._request(len(self.received))
                elif self.final_result is not None:
                    mav.mission_ack_send(msg.get_srcSystem(), msg.get_srcComponent(), self.final_result, 0)

    def _request(self, seq: int) -> None:
        if self.crosstalk:
            self.conn.mav.mission_ack_send(255, 190, mavlink2.MAV_MISSION_ACCEPTED, 0)
            self.conn.mav.mission_request_int_send(255, 190, seq + 1, 0)
            if seq == 1:
                self.conn.mav.mission_ack_send(OUR_SYSTEM, 195, mavlink2.MAV_MISSION_ACCEPTED, 0)
        if self.legacy:
            self.conn.mav.mission_request_send(OUR_SYSTEM, 195, seq, 0)
        else:
            self.conn.mav.mission_request_int_send(OUR_SYSTEM, 195, seq, 0)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1)
        self.conn.close()


def scripted_client(vehicle: ScriptedVehicle, timeouts: MissionTimeouts | None = None):
    link = Link(LinkConfig(url=f"udpout:127.0.0.1:{vehicle.port}", heartbeat_hz=5)).start()
    link.wait_for_vehicle(timeout=5)
    return link, MissionClient(link, timeouts=timeouts)


def test_legacy_mission_request_is_answered_with_mission_item_int():
    v = ScriptedVehicle(legacy=True)
    link, mc = scripted_client(v)
    try:
        items = mission(7)
        mc.upload(items)
        assert [m.seq for m in v.received] == list(range(7))
        assert [(m.x, m.y) for m in v.received] == [(i.x, i.y) for i in items]
    finally:
        link.close()
        v.close()


def test_rejection_is_an_error_not_a_success():
    v = ScriptedVehicle(final_result=mavlink2.MAV_MISSION_NO_SPACE)
    link, mc = scripted_client(v)
    try:
        with pytest.raises(MissionRejected, match="MAV_MISSION_NO_SPACE"):
            mc.upload(mission(3))
    finally:
        link.close()
        v.close()


def test_missing_ack_fails_after_retries():
    v = ScriptedVehicle(final_result=None)  # takes every item, never acknowledges
    fast = MissionTimeouts(default_s=0.2, item_s=0.05, retries=2, attempts=2)
    link, mc = scripted_client(v, fast)
    try:
        started = time.monotonic()
        with pytest.raises(MissionError, match="failed after 2 attempts"):
            mc.upload(mission(4))
        assert time.monotonic() - started < 5
        assert mc.last_stats.attempts == 2
    finally:
        link.close()
        v.close()


def test_other_gcs_traffic_and_early_acks_do_not_end_an_upload():
    v = ScriptedVehicle(legacy=False, crosstalk=True)
    link, mc = scripted_client(v)
    try:
        items = mission(6)
        mc.upload(items)
        # Success was reported only after the vehicle had every item, in order, once.
        assert [m.seq for m in v.received] == list(range(6))
    finally:
        link.close()
        v.close()
