"""The heartbeat watch judges a vehicle at its own pace (issue 33): the demo's simulated vehicle,
60 times faster than real time, sends its 1 Hz heartbeats 17 ms of wall time apart, and a timed
sample lost to its seeded drop-outs made two of them a "duplicate" (the demo's critical banner
"Heartbeats out of the vehicle's pattern: 4 duplicate in 60 s"). The same stream at its pace raises
nothing, while a second sender of the vehicle's heartbeats is still noticed (tests/test_link_hostile.py
holds the real-time cases)."""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import pytest

from gcs_pdm.mavlink import connection
from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.service.demo import demo_telemetry
from gcs_pdm.service.status_report import trust_warnings
from gcs_pdm.sim.model import Event, SimConfig, VehicleModel
from gcs_pdm.sim.telemetry import Telemetry

sys.path.insert(0, str(Path(__file__).parent))
from test_link_hostile import FakeTime, inject  # noqa: E402

SPEEDUP = 60.0
TICK_S = 0.1
FLIGHT_S = 1200.0


@pytest.fixture
def fake_time(monkeypatch):
    clock = FakeTime()
    monkeypatch.setattr(connection, "time", clock)
    return clock


def demo_vehicle_stream(seconds: float):
    """(simulated time, packet) of the demo vehicle's periodic telemetry: its rates, its seeded
    1 % drop-outs, its wire encoding (the truth held at the start: the pattern, not the flight, is tested)."""
    state = VehicleModel(SimConfig()).state()
    telemetry = Telemetry(demo_telemetry(), seed=0)
    assert telemetry.config.drop_rate > 0  # the drop-outs are what made the false duplicates
    mav = telemetry.mav
    for k in range(int(seconds / TICK_S)):
        t = k * TICK_S
        for msg in telemetry.periodic(replace(state, time_s=t)):
            packet = msg.pack(mav)
            mav.seq = (mav.seq + 1) % 256  # as MAVLink.send numbers them
            yield t, packet


def feed(link: Link, fake_time: FakeTime, speedup: float, copycat_every_s: float | None = None) -> None:
    """The demo's vehicle at ``speedup``; with ``copycat_every_s``, a second sender repeating its
    heartbeat 2 ms of wall time (0.12 s of the vehicle's) after one of its heartbeats that often."""
    copycat = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    copycat.seq = 200
    wall0, next_copy = fake_time.now, 0.0
    for t, packet in demo_vehicle_stream(FLIGHT_S):
        fake_time.now = max(fake_time.now, wall0 + t / speedup)
        inject(link, packet, fake_time)
        if copycat_every_s is not None and packet[7] == 0 and t >= next_copy:  # msgid 0: HEARTBEAT
            next_copy = t + copycat_every_s
            fake_time.now += 0.002
            heard = mavlink2.MAVLink(None).decode(bytearray(packet))  # the vehicle's own, its own counter
            inject(link, heard.pack(copycat), fake_time)
            copycat.seq += 1


def link_trust_banners(link: Link) -> list[str]:
    """The console's link-trust banners of the link's state (an unsigned link's standing advice aside)."""
    return [w["kind"] for w in trust_warnings({"available": True, **link.trust_report()}) if w["kind"] != "unsigned_link"]


def test_the_demo_vehicle_at_its_speedup_raises_no_heartbeat_banner(fake_time):
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    feed(link, fake_time, SPEEDUP)
    watch = link.trust_report()["heartbeats"]
    assert watch["heartbeats"] > 0.9 * FLIGHT_S  # 1 Hz, less the drop-outs
    assert watch["anomalies"] == dict.fromkeys(("duplicate", "identity", "out_of_sequence", "uncorroborated"), 0)
    assert not watch["suspected"] and link_trust_banners(link) == []


def test_a_second_sender_beside_the_fast_demo_vehicle_is_still_noticed(fake_time):
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    feed(link, fake_time, SPEEDUP, copycat_every_s=60.0)
    watch = link.trust_report()["heartbeats"]
    assert watch["anomalies"]["duplicate"] >= 3 and watch["suspected"]
    assert "heartbeat_spoofing" in link_trust_banners(link)


def test_the_demo_vehicle_sends_no_heartbeat_beside_an_events_heartbeat():
    """The demo vehicle sent one heartbeat per event, then its periodic one: arming and the mode
    change (and later landing and disarming) gave identical heartbeats back to back with no timed
    sample between (the two "duplicates" left in an instrumented demo, 0.4 and 2.6 ms apart, once
    the watch judged at the vehicle's pace). Now one heartbeat announces them and restarts the
    period; the recorded fixtures' telemetry keeps all three."""
    state = VehicleModel(SimConfig()).state()

    def heartbeats_in_a_tick(config) -> int:
        telemetry = Telemetry(config, seed=0)
        telemetry.periodic(replace(state, time_s=0.0))
        # arming and the mode change at once, as the vehicle starts its mission
        msgs = telemetry.events([Event(1.0, "armed"), Event(1.0, "mode")], replace(state, time_s=1.0)) + \
            telemetry.periodic(replace(state, time_s=1.0))
        return sum(m.get_type() == "HEARTBEAT" for m in msgs)

    demo = demo_telemetry()
    assert heartbeats_in_a_tick(demo) == 1
    assert heartbeats_in_a_tick(replace(demo, event_heartbeat_restarts_period=False)) == 3


def test_heartbeats_of_two_quick_mode_changes_are_no_duplicate_the_same_one_twice_is(fake_time):
    """Two commands in quick succession are each acknowledged by a heartbeat of the new state (a
    change announced, not a second sender); the very same heartbeat twice is still a duplicate."""
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    state = VehicleModel(SimConfig()).state()
    telemetry = Telemetry(demo_telemetry(), seed=0)
    mav = telemetry.mav

    def send(msgs) -> None:
        for msg in msgs:
            inject(link, msg.pack(mav), fake_time)
            mav.seq = (mav.seq + 1) % 256

    for k in range(20):  # the vehicle's timed stream and heartbeats, at real time
        send(telemetry.periodic(replace(state, time_s=float(k))))
        fake_time.sleep(1.0)
    send(telemetry.heartbeat(replace(state, mode="RTL")) + telemetry.heartbeat(replace(state, mode="AUTO")))
    assert link.trust_report()["heartbeats"]["anomalies"]["duplicate"] == 0
    send(telemetry.heartbeat(replace(state, mode="AUTO")))
    assert link.trust_report()["heartbeats"]["anomalies"]["duplicate"] == 1
