"""Asking the vehicle for the streams the service needs (gcs_pdm.mavlink.stream_requests, pure) and
the service doing it over a real link (service/stream_watch.py): a simulated vehicle that sends no
BATTERY_STATUS until asked gets asked, sends it, and /status says what was asked for and what came."""
from __future__ import annotations

import socket
import time

import pytest

from gcs_pdm.mavlink.stream_requests import (ACCEPTED, EXTRA3, SET_MESSAGE_INTERVAL, StreamPolicy,
                                             StreamRequests)

ONLY_BATTERY = {"battery": 2.0, "position": 0.0, "airspeed": 0.0, "esc": 0.0, "wind": 0.0, "ambient": 0.0,
                "landed": 0.0, "mission": 0.0}


def test_nothing_is_asked_before_the_vehicle_is_heard_nor_within_the_grace():
    req = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=2.0))
    assert req.due(100.0) == []
    req.on_vehicle(100.0)
    assert req.due(101.9) == []
    (ask,) = req.due(102.0)
    assert (ask.stream, ask.msgid, ask.interval_us, ask.rate_hz, ask.data_streams) == ("battery", 147, 500_000, 2.0, ())


def test_a_stream_that_comes_by_itself_is_never_asked_for():
    req = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY))
    req.on_vehicle(0.0)
    for k in range(40):
        req.on_message("BATTERY_STATUS", 0.5 * k)
        assert req.due(0.5 * k) == []
    rep = req.report(20.0)["streams"]["battery"]
    assert rep["state"] == "receiving" and rep["asks"] == 0 and rep["rate_hz_measured"] == pytest.approx(2.0)
    assert rep["rate_hz_asked"] is None


def test_a_stream_set_to_come_slowly_is_not_taken_for_a_stopped_one():
    req = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=0.0, stale_s=5.0))
    req.on_vehicle(0.0)
    req.on_message("BATTERY_STATUS", 0.0)
    for k in range(1, 6):  # every 8 s: slower than the 2 Hz setting, and than stale_s
        req.on_message("BATTERY_STATUS", 8.0 * k)
        assert req.due(8.0 * k + 7.9) == []
    assert req.report(47.9)["streams"]["battery"]["state"] == "receiving"
    assert req.report(40.0 + 3 * 8.0 + 0.1)["streams"]["battery"]["state"] == "stopped"  # three periods silent


def test_asks_back_off_and_start_over_when_a_stream_that_came_stops():
    req = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=0.0, retry_s=2.0, max_retry_s=16.0))
    req.on_vehicle(0.0)
    asked = [t / 10 for t in range(0, 1200) if req.due(t / 10)]  # 0 .. 120 s, every 0.1 s
    gaps = [round(b - a, 1) for a, b in zip(asked, asked[1:])]
    assert gaps[:5] == [2.0, 4.0, 8.0, 16.0, 16.0]  # doubling up to the ceiling
    assert req.report(120.0)["streams"]["battery"]["state"].startswith("asked ")
    assert "may not have it" in req.report(120.0)["streams"]["battery"]["state"]
    for k in range(10):  # it comes at last, then stops
        req.on_message("BATTERY_STATUS", 120.0 + 0.5 * k)
    assert req.report(125.0)["streams"]["battery"]["state"] == "receiving"
    assert req.due(126.0) == []
    assert req.report(130.0)["streams"]["battery"]["state"] == "stopped"
    assert len(req.due(130.0)) == 1 and req.due(131.0) == []  # asked again at once, then after retry_s
    assert len(req.due(132.0)) == 1


def test_request_data_stream_is_added_when_the_vehicle_refuses_or_ignores_the_command():
    req = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=0.0))
    req.on_vehicle(0.0)
    assert req.due(0.0)[0].data_streams == ()
    req.on_ack(SET_MESSAGE_INTERVAL, 3)  # MAV_RESULT_UNSUPPORTED
    (ask,) = req.due(2.0)
    assert ask.data_streams == (EXTRA3,)  # BATTERY_STATUS is in ArduPilot's EXTRA3 group
    # a vehicle that accepts the command is asked with it alone
    ok = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=0.0))
    ok.on_vehicle(0.0)
    ok.due(0.0)
    ok.on_ack(SET_MESSAGE_INTERVAL, ACCEPTED)
    assert [a.data_streams for a in (ok.due(2.0) + ok.due(6.0))] == [(), ()]
    # silence (no ACK at all): from the second ask on, the old way too
    silent = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=0.0))
    silent.on_vehicle(0.0)
    assert [a.data_streams for a in (silent.due(0.0) + silent.due(2.0) + silent.due(6.0))] == [(), (), (EXTRA3,)]
    assert silent.report(6.0)["set_message_interval"] == {"accepted": 0, "refused": 0, "last_refusal": None}


def test_a_rate_of_zero_is_never_asked_and_bad_settings_are_refused():
    req = StreamRequests(StreamPolicy(rates_hz=ONLY_BATTERY, grace_s=0.0))
    req.on_vehicle(0.0)
    assert [a.stream for a in req.due(1.0)] == ["battery"]
    rep = req.report(1.0)
    assert rep["streams"]["esc"]["state"] == "not asked (rate 0)" and rep["missing"] == ["battery"]
    with pytest.raises(ValueError, match="unknown stream"):
        StreamPolicy(rates_hz={"batt": 1.0})
    with pytest.raises(ValueError, match="0 \\(never ask\\) to 50 Hz"):
        StreamPolicy(rates_hz={"battery": -1.0})


def test_the_settings_carry_the_rates():
    from gcs_pdm.service.config import ConfigError, load_config

    cfg = load_config(env={"GCS_PDM_STREAM_RATES_HZ": '{"battery": 5}'})
    assert cfg.stream_rates_hz["battery"] == 5.0 and cfg.stream_rates_hz["position"] == 2.0
    with pytest.raises(ConfigError, match="stream_rates_hz: unknown stream"):
        load_config(env={}, stream_rates_hz={"volts": 1.0})


# --- over a real link, beside the simulated vehicle -----------------------------------------------------

def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(cond, what: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what}")
        time.sleep(0.05)


def test_the_service_asks_a_vehicle_that_sends_no_battery_status_and_says_so(tmp_path):
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.demo import demo_telemetry, sim_config, table3_mission
    from gcs_pdm.service.runtime import Service
    from gcs_pdm.service.server import start_mavlink, stop_mavlink
    from gcs_pdm.sim.telemetry import TelemetryConfig
    from gcs_pdm.sim.vehicle import SimulatedVehicle

    scenario, mission = table3_mission()
    port = _free_udp_port()
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="streams-token-0123456789",
                              mavlink_url=f"udpin:127.0.0.1:{port}", record_tlog=False, vehicle="edge540"))
    start_mavlink(svc)
    silent_battery = TelemetryConfig(rates_hz={**demo_telemetry().rates_hz, "BATTERY_STATUS": 0.0, "WIND": 0.0})
    vehicle = SimulatedVehicle(sim_config(scenario, mission), f"udpout:127.0.0.1:{port}", speedup=1.0,
                               telemetry=silent_battery).start()
    try:
        _wait(lambda: (svc.state.get("streams") or {}).get("vehicle_identified"), "the vehicle identified")
        _wait(lambda: svc.state.get("streams")["streams"]["battery"]["asks"] >= 1, "battery asked for")
        _wait(lambda: svc.state.get("streams")["streams"]["battery"]["state"] == "receiving", "battery received")
        streams = svc.state.get("streams")
        battery = streams["streams"]["battery"]
        assert battery["rate_hz_asked"] == 2.0 and battery["received"] >= 1
        assert vehicle.core.telemetry.rates["BATTERY_STATUS"] == pytest.approx(2.0)  # the vehicle took the rate
        # what came by itself was not asked for; what the simulated vehicle does not have is asked, and said
        assert streams["streams"]["position"]["asks"] == 0 and streams["streams"]["position"]["state"] == "receiving"
        # the simulated vehicle sends WIND only when asked: asked for, once at least
        assert streams["streams"]["wind"]["asks"] >= 1
        assert streams["set_message_interval"]["accepted"] >= 1
        # and the estimator gets its pack frames
        _wait(lambda: svc.loop.estimator.ready(), "the estimator ready on the asked-for battery stream")
        from fastapi.testclient import TestClient

        from gcs_pdm.service.api import create_app

        body = TestClient(create_app(svc)).get("/status").json()
        assert body["streams"]["streams"]["battery"]["state"] == "receiving"
    finally:
        vehicle.stop()
        stop_mavlink(svc)
        svc.close()
