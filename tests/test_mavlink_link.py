"""The live link: frames seen live equal frames replayed from its tlog; signing; shared reader."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

from gcs_pdm.frames import MotorFrame, PackFrame, PositionFrame, StatusFrame
from gcs_pdm.mavlink.connection import Link, LinkConfig, load_signing_key
from gcs_pdm.mavlink.dialect import mavlink2, mavutil
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.mavlink.tlog import scan_tlog

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402
from mavlink_peers import free_tcp_port, free_udp_port  # noqa: E402
from tlog_corpus import TLOG_DIR  # noqa: E402


def fake_vehicle(port: int, **kwargs):
    return mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                      dialect="ardupilotmega", **kwargs)


def send_flight(vehicle, seconds: int = 20) -> int:
    """A burst of telemetry as a fast simulated vehicle would send it (no pauses)."""
    mav = vehicle.mav
    sent = 0
    for step in range(seconds * 10):
        boot_ms = 60_000 + step * 100
        mav.global_position_int_send(boot_ms, 473977419 + step, 85455938, 500_000, 100_000, 1500, 0, 0, 9000)
        mav.scaled_pressure_send(boot_ms + 5, 1013.0, 0.1, 2100 + step % 7)
        mav.esc_telemetry_1_to_4_send([60, 58, 0, 0], [2200] * 4, [1200 + step, 990, 0, 0], [0] * 4,
                                      [5400, 5300, 0, 0], [0] * 4)
        for pack in range(4):
            mav.battery_status_send(pack, 0, 0, 2500 + pack, [4100, 4100, 4100, 4100, 4100] + [65535] * 5,
                                    1500 - step, -1, -1, -1)
        mav.vfr_hud_send(18.0, 17.5, 90, 55, 120.0, 0.5)
        sent += 8
        if step % 10 == 0:
            mav.heartbeat_send(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                               0x80 | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 10, 4)
            mav.mission_current_send(step // 10)
            sent += 2
    return sent


def wait_for(condition, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return bool(condition())


def test_live_frames_equal_replayed_frames(tmp_path):
    port = free_udp_port()
    tlog = tmp_path / "live.tlog"
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", tlog_path=str(tlog), heartbeat_hz=20))
    live = []
    link.add_frame_listener(live.append)
    telemetry = link.subscribe(["HEARTBEAT"])  # a second consumer on the same reader
    link.start()
    assert link.rcvbuf_effective is None or link.rcvbuf_effective > 200_000
    vehicle = fake_vehicle(port)
    vehicle.mav.heartbeat_send(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3)
    assert wait_for(lambda: link.mapper.locked)
    sent = send_flight(vehicle) + 1
    assert wait_for(lambda: link.received >= sent)
    time.sleep(0.2)  # let the link's own heartbeats go out to the now known peer
    link.close()
    vehicle.close()
    assert link.received == sent  # nothing dropped in the burst
    assert telemetry.queue.qsize() == 21

    replayed = []
    summary = replay_tlog(tlog, frame_consumer=replayed.append)
    assert replayed == live
    kinds = summary.mapping["frames_by_kind"]
    assert kinds == {"airdata": 200, "ambient": 200, "mission_progress": 20, "motor": 400, "pack": 800,
                     "position": 200, "status": 21}
    # The first heartbeat came before any timed message: back-dated from the first position.
    assert isinstance(live[0], StatusFrame) and not live[0].armed and 55.0 < live[0].time_s <= 60.0
    # Untimed messages carry the latest vehicle time: SCALED_PRESSURE said 60.005 s.
    ura = next(f for f in live if isinstance(f, PackFrame) and f.pack == "URA40")
    assert ura == PackFrame(60.005, "URA40", pytest.approx(20.5), 15.0, pytest.approx(25.03))
    assert [f for f in live if isinstance(f, MotorFrame)][:2] == [
        MotorFrame(60.005, "fwd", 12.0, 5400, 60), MotorFrame(60.005, "aft", 9.9, 5300, 58)]
    # The tlog holds what was sent too: the service's own heartbeats as 245/195 (not the GCS's 255).
    sources = {(sysid, compid) for _, _, sysid, compid, *_ in scan_tlog(tlog)}
    assert sources == {(1, 1), (245, 195)}


def test_signed_link_accepts_signed_and_rejects_unsigned(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text("correct horse battery staple\n")
    key = load_signing_key(key_file)
    assert len(key) == 32
    port = free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", signing_key_file=str(key_file))).start()
    try:
        unsigned = fake_vehicle(port)
        unsigned.mav.heartbeat_send(1, 3, 0, 0, 3)
        time.sleep(0.3)
        assert not link.mapper.locked  # unsigned heartbeat refused
        signed = fake_vehicle(port)
        signed.setup_signing(key, sign_outgoing=True)
        signed.mav.heartbeat_send(1, 3, 0, 0, 3)
        assert wait_for(lambda: link.mapper.locked)
        unsigned.close()
        signed.close()
    finally:
        link.close()


def test_signing_key_formats(tmp_path):
    raw = bytes(range(32))
    (tmp_path / "raw").write_bytes(raw)
    (tmp_path / "hex").write_text(raw.hex())
    assert load_signing_key(tmp_path / "raw") == raw
    assert load_signing_key(tmp_path / "hex") == raw
    (tmp_path / "empty").write_text("   \n")
    with pytest.raises(ValueError, match="empty"):
        load_signing_key(tmp_path / "empty")


@pytest.mark.skipif(not (TLOG_DIR / "MarcusUWA_EAICS_flight.tlog").is_file(), reason=f"no tlog corpus at {TLOG_DIR}")
def test_fast_udp_replay_into_a_live_link_loses_nothing():
    """A tlog re-sent over UDP at 100x real time (~10,000 msg/s) reaches the link whole and maps
    to the same frames as a direct replay: message time, not receive time, stamps them."""
    path = TLOG_DIR / "MarcusUWA_EAICS_flight.tlog"
    direct = []
    summary = replay_tlog(path, frame_consumer=direct.append)
    port = free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", heartbeat_hz=0))
    live = []
    link.add_frame_listener(live.append)
    link.start()
    try:
        replay_tlog(path, speed=100.0, udp_target=f"127.0.0.1:{port}")
        assert wait_for(lambda: link.received >= summary.messages, timeout=10)
    finally:
        link.close()
    assert link.received == summary.messages and link.bad_data == 0
    # Frames held for the clock at start-up are back-dated by receive time, which pacing
    # compresses; from the first timed frame on, live and direct replay agree exactly.
    first_timed = next(i for i, f in enumerate(direct) if isinstance(f, PositionFrame))
    assert len(live) == len(direct)
    assert live[first_timed:] == direct[first_timed:]


def test_tcp_link_receives_from_a_tcp_server():
    port = free_tcp_port()
    vehicle = mavutil.mavlink_connection(f"tcpin:127.0.0.1:{port}", source_system=1, source_component=1,
                                         dialect="ardupilotmega")
    link = Link(LinkConfig(url=f"tcp:127.0.0.1:{port}", heartbeat_hz=10)).start()
    try:
        # tcpin accepts the link's connection when it next reads; the link's heartbeat gets there.
        assert wait_for(lambda: vehicle.recv_match(type="HEARTBEAT", blocking=True, timeout=0.1) is not None)
        vehicle.mav.heartbeat_send(1, 3, 0x80, 0, 4)
        vehicle.mav.global_position_int_send(1000, 1, 2, 3, 4, 5, 6, 7, 8)
        assert wait_for(lambda: link.mapper.locked and link.received >= 2)
    finally:
        link.close()
        vehicle.close()


def test_serial_link_over_a_pty():
    pytest.importorskip("serial", reason="pyserial is needed for serial links")
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    link = Link(LinkConfig(url=os.ttyname(slave), baud=115200, heartbeat_hz=20)).start()
    try:
        v = PacketFactory()
        os.write(master, v.heartbeat() + v.position(1000) + v.position(1100) + v.battery(0, [4000] * 5, 100, 2000))
        assert wait_for(lambda: link.received == 4)
        assert dict(link.mapper.stats.frames_by_kind) == {"status": 1, "position": 2, "pack": 1}
        assert wait_for(lambda: len(os.read(master, 4096)) > 0)  # the link's heartbeat goes out too
    finally:
        link.close()
        os.close(master)
        os.close(slave)
