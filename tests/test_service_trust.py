"""/status and /health show what the link refused to believe (issue 12): foreign systems sending
vehicle heartbeats are reported at once (one event per system, a log warning), never tracked."""
from __future__ import annotations

import logging
import socket
import sys
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.runtime import Service

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402
from mavlink_peers import free_udp_port  # noqa: E402


class LinkOnlyLoop:
    """The part of a live loop the status report reads: its link (no estimator, no planner)."""

    def __init__(self, link):
        self.link = link

    def stop(self) -> None:
        self.link.close()


@pytest.fixture
def service(tmp_path):
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="trust-test-token-0123456"))
    yield svc
    svc.close()


def wait_for(condition, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_without_a_link_the_report_says_why(service):
    client = TestClient(create_app(service))
    assert client.get("/status").json()["link_trust"] == {"available": False, "reason": "no MAVLink link"}
    assert client.get("/health").json()["foreign_systems"] == []


def test_foreign_vehicles_are_reported_in_status_health_events_and_log(service, caplog):
    port = free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", heartbeat_hz=0)).start()
    service.attach_loop(LinkOnlyLoop(link))
    service.foreign_watch.period_s = 0.05
    client = TestClient(create_app(service))
    vehicle, intruders = PacketFactory(1, 1), (PacketFactory(42, 1), PacketFactory(43, 1))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, caplog.at_level(logging.WARNING):
        tx.sendto(vehicle.heartbeat(), ("127.0.0.1", port))
        for _ in range(3):
            for intruder in intruders:
                tx.sendto(intruder.heartbeat(), ("127.0.0.1", port))
        wait_for(lambda: sum(e.kind == "foreign_system" for e in service.events.since(0)) == 2)
        tx.sendto(intruders[0].heartbeat(), ("127.0.0.1", port))
        wait_for(lambda: client.get("/status").json()["link_trust"]["foreign_systems"][0]["heartbeats"] == 4)
        time.sleep(0.2)  # several watcher periods: a system is reported once, however often it is heard

    trust = client.get("/status").json()["link_trust"]
    assert trust["available"] is True and trust["target_system"] == 1
    assert {f["system"]: f["heartbeats"] for f in trust["foreign_systems"]} == {42: 4, 43: 3}
    assert {"time_rejected", "gated", "bad_data", "clock"} <= set(trust)
    assert client.get("/health").json()["foreign_systems"] == [42, 43]
    events = [e.data for e in service.events.since(0) if e.kind == "foreign_system"]
    assert sorted(e["system"] for e in events) == [42, 43] and all(e["tracked_system"] == 1 for e in events)
    for system in (42, 43):
        assert sum(f"system {system} " in r.getMessage() and r.levelno == logging.WARNING
                   for r in caplog.records) == 1
    assert link.target_system == 1  # the vehicle, never an intruder


def test_a_second_sender_on_the_vehicles_id_degrades_health_and_warns_in_status(service):
    from gcs_pdm.mavlink.dialect import mavlink2

    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    service.attach_loop(LinkOnlyLoop(link))
    client = TestClient(create_app(service))
    ours, other = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)
    other.mav.seq = 99
    for k in range(80):
        for sender in (ours, other):
            packet = sender.heartbeat() if k % 10 == 0 else sender.battery(0, [4000] * 4, 1500, 3000)
            link.handle_message(mavlink2.MAVLink(None).decode(bytearray(packet)))
    status = client.get("/status").json()
    assert status["link_trust"]["sequence"]["shared"]
    # the two senders' heartbeats interleave out of sequence too; the link is not signed
    assert [w["kind"] for w in status["warnings"]] == ["shared_vehicle_id", "heartbeat_spoofing", "unsigned_link"]
    health = client.get("/health").json()
    assert health["status"] == "degraded" and "more than one sender" in health["reasons"][0]
    assert not any("not signed" in r or "no signing key" in r for r in health["reasons"])  # said, not degraded


def test_one_sender_raises_no_warning(service):
    from gcs_pdm.mavlink.dialect import mavlink2

    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    service.attach_loop(LinkOnlyLoop(link))
    client = TestClient(create_app(service))
    ours = PacketFactory(1, 1, numbered=True)
    for k in range(200):
        packet = ours.heartbeat() if k % 10 == 0 else ours.battery(0, [4000] * 4, 1500, 3000)
        link.handle_message(mavlink2.MAVLink(None).decode(bytearray(packet)))
    assert client.get("/status").json()["link_trust"]["sequence"]["verdict"] == "one sender"
    # the one warning left: the link is not signed (a banner, not a degraded /health)
    assert [w["kind"] for w in client.get("/status").json()["warnings"]] == ["unsigned_link"]
    assert client.get("/health").json()["status"] == "ok"


def test_timestamps_and_heartbeats_another_sender_makes_degrade_health(service, monkeypatch):
    """Issue 34: steps ahead the vehicle does not follow and heartbeats without its telemetry are
    each a critical /status warning and a /health reason."""
    from gcs_pdm.mavlink import connection
    from gcs_pdm.mavlink.dialect import mavlink2

    class FakeTime:
        now = 100.0

        def monotonic(self):
            return self.now

        def time(self):
            return 1.7e9 + self.now

    clock = FakeTime()
    monkeypatch.setattr(connection, "time", clock)
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    service.attach_loop(LinkOnlyLoop(link))
    client = TestClient(create_app(service))
    vehicle, other = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)

    def inject(packet):
        msg = mavlink2.MAVLink(None).decode(bytearray(packet))
        msg._timestamp = clock.time()
        link.handle_message(msg)

    for k in range(100):  # 10 s: the vehicle at 10 Hz, another sender's position 9.9 s ahead once a second
        if k % 10 == 0:
            inject(vehicle.heartbeat())
        inject(vehicle.position(30_000 + k * 100))
        if k % 10 == 5:
            inject(other.position(30_000 + k * 100 + 9_900))
        clock.now += 0.1
    kinds = {w["kind"]: w for w in client.get("/status").json()["warnings"]}
    assert kinds["clock_spoofing"]["level"] == "critical"
    health = client.get("/health").json()
    assert health["status"] == "degraded" and any("another sender uses the vehicle's ids" in r for r in health["reasons"])
    for _ in range(5):  # the vehicle goes silent; its heartbeat keeps coming from someone
        inject(other.heartbeat())
        clock.now += 1.0
    kinds = {w["kind"] for w in client.get("/status").json()["warnings"]}
    assert "heartbeat_spoofing" in kinds
    assert any("heartbeats count only with the vehicle's timed telemetry" in r
               for r in client.get("/health").json()["reasons"])
