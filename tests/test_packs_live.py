"""The live service and each pack's life: the next flight's estimator starts from the pack's latest
health, and a health point is recorded under the serial number the autopilot reports
(SMART_BATTERY_INFO), heard through a real link from a simulated sender."""
from __future__ import annotations

import math
import socket
import time

import pytest
from pymavlink import mavutil

from gcs_pdm.frames import PackFrame, StatusFrame
from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.packs.health import HealthPoint
from gcs_pdm.packs.identity import AUTOPILOT
from gcs_pdm.packs.priors import prior_with_history, series_resistance_of_pulse
from gcs_pdm.service.config import load_config
from gcs_pdm.service.live import LiveLoop
from gcs_pdm.service.runtime import Service
from service_stand_ins import FakeLink, NoMissions, fly_rested_pack  # tests/service_stand_ins.py

TOKEN = "packs-live-test-token-0123456789"


def service(tmp_path, **kw):
    return Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, vehicle="quad-4s", **kw))


def stored_health(svc, pack_id: str, capacity_ah: float, capacity_sd_ah: float, resistance_ohm: float,
                  resistance_sd_ohm: float, slot: str) -> None:
    spec = svc.vehicle.packs[0]
    hp = HealthPoint(pack_id=pack_id, start_s=0.0, end_s=900.0, capacity_ah=capacity_ah, capacity_sd_ah=capacity_sd_ah,
                     resistance_25c_ohm=resistance_ohm, resistance_sd_ohm=resistance_sd_ohm, charge_ah=3.0,
                     energy_wh=44.0, equivalent_cycles=0.6, depth_of_discharge=0.6, peak_temperature_c=31.0,
                     nominal_capacity_ah=spec.capacity_mah / 1000.0, cells_series=spec.cells_series)
    svc.packs.add_live_point(7, slot, "operator assignment", hp, {"start_s": 0.0, "end_s": 900.0})


def test_the_pulse_resistance_is_read_as_the_filters_series_resistance():
    # the filter's pair builds rho R0 (1 - e^(-1/tau)) in the pulse's second: that much is not R0
    r0, share = series_resistance_of_pulse(0.05, r1_ratio=1.0, tau1_s=1.0 / math.log(2.0))
    assert r0 == pytest.approx(0.05 / 1.5) and share == pytest.approx(1.0 / 3.0)


def test_a_flight_starts_from_the_packs_stored_health(tmp_path):
    """A pack whose stored health says 0.8 of its rated capacity: the loop's estimator, and the one
    it builds for the next flight, start at 0.8 with the stored σ; another pack starts from the
    description."""
    svc = service(tmp_path)
    spec = svc.vehicle.packs[0]
    rated_ah = spec.capacity_mah / 1000.0
    svc.packs.assign(spec.name, "Q-8")
    stored_health(svc, "Q-8", 0.8 * rated_ah, 0.05, 0.060, 0.002, spec.name)
    try:
        loop = LiveLoop(svc, FakeLink(), NoMissions())
        svc.attach_loop(loop)

        def started(est):
            cal = est.calib[0]
            assert not cal.initialised
            return cal.q0 / 3600.0, cal.prior.capacity_rel_sd, cal.prior.r0_ohm, cal.prior.capacity_source

        for est in (loop.estimator, None):
            if est is None:  # a flight begins and ends, and the next begins: new filters
                for t, armed in ((10.0, True), (20.0, False), (30.0, True)):
                    loop.process(StatusFrame(t, armed, "AUTO", 4))
                est = loop.estimator
            cap, rel_sd, r0, source = started(est)
            assert cap == pytest.approx(0.8 * rated_ah)
            assert rel_sd == pytest.approx(0.05 / (0.8 * rated_ah))
            assert r0 < 0.060 and r0 == pytest.approx(series_resistance_of_pulse(
                0.060, est.calib[0].chem.r1_ratio, est.calib[0].chem.tau1_s)[0])
            assert "pack history (Q-8)" in source
            assert "pack history (Q-8" in svc.state.get("pack_priors")[spec.name]
        # once the estimator has a frame, its capacity is what the history said, with that σ
        loop.process(PackFrame(31.0, spec.name, 16.4, 0.0, 25.0))
        rep = loop.estimator.calib[0].report()
        assert rep["capacity_ah"] == pytest.approx(0.8 * rated_ah, rel=1e-3)
        assert rep["capacity_source"] == "pack history (Q-8)"
    finally:
        svc.close()

    # without history the description's capacity and its wide σ
    base = loop.estimator.calib[0].prior
    assert prior_with_history(base, None) is base
    fresh = service(tmp_path / "fresh")
    try:
        loop = LiveLoop(fresh, FakeLink(), NoMissions())
        cal = loop.estimator.calib[0]
        assert cal.q0 / 3600.0 == pytest.approx(rated_ah) and cal.prior.capacity_source != "pack history (Q-8)"
        assert "no flight of this pack" in fresh.state.get("pack_priors")[spec.name]
    finally:
        fresh.close()


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_a_live_flights_health_point_goes_to_the_serial_the_autopilot_reports(tmp_path):
    """A simulated vehicle sends HEARTBEAT and SMART_BATTERY_INFO (battery 0, serial SN-4711) over
    UDP to the service's link; the flight's health point is stored under SN-4711, not the operator's
    assignment to the slot nor the slot's name."""
    svc = service(tmp_path)
    spec = svc.vehicle.packs[0]
    svc.packs.assign(spec.name, "Q-1")
    port = _free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", heartbeat_hz=0)).start()
    sender = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                        dialect="ardupilotmega")
    loop = LiveLoop(svc, link, NoMissions())
    svc.attach_loop(loop)
    try:
        serials = svc.flights.serials
        deadline = time.monotonic() + 10.0
        while serials.latest(spec.name) is None and time.monotonic() < deadline:
            sender.mav.heartbeat_send(2, 3, 0, 0, 4)  # a quadrotor, ArduPilot
            sender.mav.smart_battery_info_send(spec.mavlink_battery_id, 0, 0, 5000, 4800, 12, b"SN-4711", b"pack",
                                               0, 3000, 3000, 3300)
            sender.mav.smart_battery_info_send(9, 0, 0, 5000, 4800, 12, b"OTHER", b"x", 0, 3000, 3000, 3300)
            time.sleep(0.05)
            serials.drain(0.0)
        assert serials.latest(spec.name) == "SN-4711"
        assert serials.unmapped_ids.get(9, 0) >= 1  # battery 9 is no pack of this vehicle: counted, not used

        cap, r, cells = spec.capacity_mah / 1000.0 * 0.9, 0.03, spec.cells_series
        fly_rested_pack(loop, spec.name, cells, cap, r, until_s=1700.0)
        assert svc.packs.points("Q-1") == []
        pack = svc.packs.summary("SN-4711")
        h = pack["history"][0]
        assert pack["flights"] == 1 and h["identity"] == AUTOPILOT
        assert abs(h["capacity_ah"] / cap - 1.0) < 0.03
        assert svc.pack_priors()[spec.name]["pack_id"] == "SN-4711"
    finally:
        loop.stop()
        link.close()
        sender.close()
        svc.close()


def test_a_swapped_pack_keeps_each_flights_serial(tmp_path):
    """The serial heard last before a flight's end is that flight's pack: a pack swapped on the
    ground after landing does not take the landed flight's point; not provided (all NULs) is no
    serial."""
    svc = service(tmp_path)
    try:
        slot, bid = svc.vehicle.packs[0].name, svc.vehicle.packs[0].mavlink_battery_id
        serials = svc.flights.serials
        serials.add(bid, b"\x00" * 16, 5.0)
        assert serials.latest(slot) is None
        serials.add(bid, b"A-1\x00\x00", 10.0)
        serials.add(bid, "A-1", 50.0)
        serials.add(bid, "B-2", 1200.0)
        assert serials.at(slot, 1000.0) == "A-1" and serials.at(slot, 1300.0) == "B-2"
        assert serials.at(slot, 0.0) == "A-1"  # heard only after the flight began: the first heard
        serials.restart_clock()  # a reboot: the last pack is still in the slot
        assert serials.at(slot, 3.0) == "B-2"
    finally:
        svc.close()
