"""The link under a hostile sender (issue 34): a wrong-key signed packet cannot blind a signed link;
spoofed heartbeats cannot keep a silent vehicle up; a sender putting timestamps 9.9 s ahead cannot
run message time away; rejected packets are counted, not logged one line each."""
from __future__ import annotations

import logging
import socket
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.mavlink import connection
from gcs_pdm.mavlink.connection import Link, LinkConfig, load_signing_key
from gcs_pdm.mavlink.dialect import mavlink2, mavutil

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402
from mavlink_peers import free_udp_port  # noqa: E402

#: MAVLink signing timestamps: 10 µs units since 2015-01-01
SIGNING_EPOCH = 1420070400
YEAR_S = 365 * 86400


def wait_for(condition, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def signed_sender(port: int, key: bytes, ahead_s: float = 0.0):
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                      dialect="ardupilotmega")
    stamp = int((time.time() - SIGNING_EPOCH + ahead_s) * 1e5)
    conn.setup_signing(key, sign_outgoing=True, initial_timestamp=stamp, link_id=0)
    return conn


def heartbeat(conn) -> None:
    conn.mav.heartbeat_send(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0x80, 10,
                            mavlink2.MAV_STATE_ACTIVE)


def test_a_wrong_key_packet_a_year_ahead_does_not_blind_a_signed_link(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text("the vehicle's passphrase\n")
    key = load_signing_key(key_file)
    port = free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", signing_key_file=str(key_file), heartbeat_hz=0)).start()
    heartbeats = link.subscribe(["HEARTBEAT"])
    vehicle = signed_sender(port, key)
    attacker = signed_sender(port, b"\x07" * 32, ahead_s=YEAR_S)  # wrong key, same ids, a year ahead
    try:
        heartbeat(vehicle)
        assert wait_for(lambda: link.mapper.locked)
        assert wait_for(lambda: heartbeats.queue.qsize() == 1)
        heartbeat(attacker)
        time.sleep(0.2)
        for _ in range(5):
            heartbeat(vehicle)
            time.sleep(0.02)
        # every genuine heartbeat after the forged one gets through (pymavlink alone refused them all)
        assert wait_for(lambda: heartbeats.queue.qsize() == 6), heartbeats.queue.qsize()
        assert link.signature_check.accepted == 6
        assert link.vehicle_silent_s() < 1.0
        report = link.trust_report()["signing"]
        assert report["signed"] is True and report["rejected"] == {"bad_signature": 1, "old_timestamp": 0,
                                                                   "stale_new_stream": 0}
    finally:
        vehicle.close()
        attacker.close()
        link.close()


def test_a_replayed_genuine_packet_is_still_refused_as_old(tmp_path):
    from gcs_pdm.mavlink.signing import SignatureCheck

    key = b"\x11" * 32
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.link_id = 0
    mav.signing.timestamp = int((time.time() - SIGNING_EPOCH) * 1e5)
    packet = mav.heartbeat_encode(1, 3, 0, 0, 4).pack(mav)
    receiver = mavlink2.MAVLink(None)
    receiver.signing.secret_key = key
    check = SignatureCheck.install(receiver)
    assert check(bytearray(packet), 1, 1) is True
    assert check(bytearray(packet), 1, 1) is False  # the same packet again: a replay
    assert check.rejected["old_timestamp"] == 1


def test_a_flood_of_forged_packets_is_counted_and_logged_once_a_minute(caplog):
    from gcs_pdm.mavlink.signing import SignatureCheck

    receiver = mavlink2.MAVLink(None)
    receiver.signing.secret_key = b"\x22" * 32
    now = [0.0]
    check = SignatureCheck.install(receiver, clock=lambda: now[0])
    forger = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    forger.signing.secret_key = b"\x33" * 32
    forger.signing.sign_outgoing = True
    forger.signing.timestamp = 1
    with caplog.at_level(logging.INFO):
        for k in range(50_000):
            now[0] = k * 0.001  # 50 s of a 1 kHz flood
            packet = forger.heartbeat_encode(1, 3, 0, 0, 4).pack(forger)
            check(bytearray(packet), 1, 1)
        now[0] = 61.0
        check(bytearray(forger.heartbeat_encode(1, 3, 0, 0, 4).pack(forger)), 1, 1)
    assert check.rejected["bad_signature"] == 50_001
    lines = [r for r in caplog.records if "refused" in r.getMessage() or "sig" in r.getMessage()]
    assert len(lines) == 2  # the first, and one a minute later with the count
    assert "50000 in the last minute" in lines[1].getMessage()


class FakeTime:
    """``time`` for the link module: wall and monotonic clocks the test moves."""

    def __init__(self, start: float = 1000.0):
        self.now = start

    def monotonic(self) -> float:
        return self.now

    def time(self) -> float:
        return 1.7e9 + self.now

    def sleep(self, s: float) -> None:
        self.now += s


def inject(link: Link, packet: bytes, clock: FakeTime) -> None:
    msg = mavlink2.MAVLink(None).decode(bytearray(packet))
    msg._timestamp = clock.time()
    link.handle_message(msg)


@pytest.fixture
def fake_time(monkeypatch):
    clock = FakeTime()
    monkeypatch.setattr(connection, "time", clock)
    return clock


def test_spoofed_heartbeats_do_not_keep_a_silent_vehicle_up(fake_time):
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    vehicle, spoofer = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)
    spoofer.mav.seq = 150  # behind the vehicle's counter (210 after its 210 packets)
    boot_ms = 100_000
    for step in range(100):  # 10 s of a healthy vehicle: 10 Hz timed telemetry, 1 Hz heartbeats
        if step % 10 == 0:
            inject(link, vehicle.heartbeat(), fake_time)
        inject(link, vehicle.position(boot_ms + step * 100), fake_time)
        inject(link, vehicle.pressure(boot_ms + step * 100 + 5), fake_time)
        fake_time.sleep(0.1)
    assert link.vehicle_silent_s() < 1.5
    silent_at = fake_time.now
    lost_after = None
    while fake_time.now - silent_at < 20.0:  # the vehicle is silent; someone sends its heartbeat at 1 Hz
        inject(link, spoofer.heartbeat(), fake_time)
        for _ in range(10):
            fake_time.sleep(0.1)
            if lost_after is None and link.vehicle_silent_s() > 5.0:  # link_lost_after_s's default
                lost_after = fake_time.now - silent_at
    print(f"spoofed 1 Hz heartbeats, silent vehicle: lost (silent > 5 s) after {lost_after} s")
    assert lost_after is not None and lost_after <= 10.0, lost_after
    assert "heartbeats without the vehicle's timed telemetry" in link.silence_cause()
    watch = link.trust_report()["heartbeats"]
    assert watch["suspected"] and watch["anomalies"]["uncorroborated"] >= 3
    assert watch["anomalies"]["out_of_sequence"] == 1  # the spoofer's first: its own counter


def test_duplicated_heartbeats_beside_a_live_vehicle_are_noticed(fake_time):
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    vehicle, copycat = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)
    copycat.mav.seq = 200
    for step in range(100):
        if step % 10 == 0:
            inject(link, vehicle.heartbeat(), fake_time)
            fake_time.sleep(0.01)
            inject(link, copycat.heartbeat(), fake_time)  # a second one 10 ms later, other counter
        inject(link, vehicle.position(50_000 + step * 100), fake_time)
        fake_time.sleep(0.1)
    watch = link.trust_report()["heartbeats"]
    # every pair but the first, which came before the vehicle clock had its time (nothing to tell by)
    assert watch["anomalies"]["duplicate"] == 9 and watch["suspected"]
    assert "another sender may use the vehicle's ids" in watch["reason"]


def test_a_lone_vehicle_raises_no_heartbeat_or_clock_suspicion(fake_time):
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    vehicle = PacketFactory(1, 1, numbered=True)
    for step in range(300):
        if step % 10 == 0:
            inject(link, vehicle.heartbeat(), fake_time)
        if step == 150:
            fake_time.sleep(4.0)  # a 4-s outage: the vehicle's time moves with the receive time
        inject(link, vehicle.position(20_000 + step * 100 + (4000 if step >= 150 else 0)), fake_time)
        fake_time.sleep(0.1)
    report = link.trust_report()
    assert not report["heartbeats"]["suspected"] and report["heartbeats"]["anomalies"] == dict.fromkeys(
        ("duplicate", "identity", "out_of_sequence", "uncorroborated"), 0)
    assert report["clock"]["rejected"] == 0 and not report["clock"]["spoof_suspected"]
    assert link.vehicle_silent_s() < 1.5


def test_signing_init_writes_a_key_the_service_reads_and_says_how_to_set_it_up(tmp_path, capsys):
    from gcs_pdm.cli import main

    key_file = tmp_path / "signing.key"
    assert main(["signing", "init", "--key-file", str(key_file)]) == 0
    out = capsys.readouterr().out
    passphrase = key_file.read_text().strip()
    assert (key_file.stat().st_mode & 0o777) == 0o600 and len(passphrase) == 24
    key = load_signing_key(key_file)
    assert f"signing setup {passphrase}" in out and "SETUP_SIGNING" in out and "QGroundControl" in out
    assert key.hex() in out  # the key the passphrase gives (SHA-256), for tools that take raw bytes
    assert main(["signing", "init", "--key-file", str(key_file)]) == 2  # never overwritten by accident
    assert key_file.read_text().strip() == passphrase


def test_status_says_whether_the_link_is_signed(tmp_path):
    from fastapi.testclient import TestClient

    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service

    class LinkOnlyLoop:
        def __init__(self, link):
            self.link = link

        def stop(self):
            self.link.close()

    key_file = tmp_path / "key"
    key_file.write_text("a passphrase for the test\n")
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="signed-status-token-Zq81"))
    try:
        for key, signed in ((str(key_file), True), (None, False)):
            link = Link(LinkConfig(url=f"udpin:127.0.0.1:{free_udp_port()}", signing_key_file=key, heartbeat_hz=0))
            link.open()
            svc.attach_loop(LinkOnlyLoop(link))
            status = TestClient(create_app(svc)).get("/status").json()
            assert status["link_trust"]["signing"]["signed"] is signed
            kinds = [w["kind"] for w in status.get("warnings", [])]
            assert ("unsigned_link" in kinds) is not signed
            link.close()
    finally:
        svc.close()


def test_a_fault_every_packet_hits_is_counted_and_logged_once_a_minute(caplog):
    """A consumer failing on every packet used to write one traceback per packet (a full disk: 21,042
    in 48 s); the reader counts them and logs the traceback at most once a minute."""
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    vehicle = PacketFactory(1, 1, numbered=True)
    messages = [mavlink2.MAVLink(None).decode(bytearray(vehicle.battery(0, [4000] * 4, 1500, 2500)))
                for _ in range(2000)]

    class Conn:
        def recv_msg(self):
            if messages:
                return messages.pop()
            link._stop.set()
            return None

        def select(self, _timeout):
            pass

    def broken(*_args):
        raise RuntimeError("a consumer's bug")

    link.conn = Conn()
    link.mapper.feed = broken
    with caplog.at_level(logging.WARNING):
        link._run()
    assert link.handle_failures == 2000 and link.trust_report()["handle_failures"] == 2000
    assert sum("failed to handle" in r.getMessage() for r in caplog.records) == 1
