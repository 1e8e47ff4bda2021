"""The service on a vehicle description, without a network: readiness said out loud, a replan that
cannot run refused with the reason, a provisional description adopted by the live loop (the link
re-mapped, the estimator and diagnoser built from it), operator faults by the description's motors."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_service_live_loop import FakeLink, FakeVehicleMissions  # noqa: E402

from gcs_pdm.frames import MotorFrame, PackFrame  # noqa: E402
from gcs_pdm.mavlink.mapping import FrameMapper  # noqa: E402
from gcs_pdm.service.config import load_config  # noqa: E402
from gcs_pdm.service.live import LiveLoop  # noqa: E402
from gcs_pdm.service.runtime import Service  # noqa: E402
from gcs_pdm.service.storage import Conflict  # noqa: E402
from gcs_pdm.service.vehicle_discovery import AwaitingVehicle  # noqa: E402
from gcs_pdm.vehicle.presets import PRESETS  # noqa: E402
from gcs_pdm.vehicle.provisional import ProvisionalObserver  # noqa: E402
from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping, waiting_mapping  # noqa: E402


class Subscription:
    def get(self, timeout=None):
        return None

    def close(self):
        pass


def _loop(tmp_path, vehicle=None, **kw):
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="vehicle-test-token-8Rw2", vehicle=vehicle))
    link = FakeLink()
    link.mapper = FrameMapper(waiting_mapping(), target_system=1)
    link.subscribe = lambda types: Subscription()
    loop = LiveLoop(svc, link, FakeVehicleMissions([]), **kw)
    svc.attach_loop(loop)
    return svc, loop


def test_readiness_and_the_replan_refusal_follow_the_description(tmp_path):
    svc, loop = _loop(tmp_path, "quad-4s")
    r = svc.state.get("readiness")
    assert r["state"].startswith("waiting for pack battery voltage") and r["motor_telemetry"] == "no ESC telemetry"
    assert r["motor_diagnosis"].startswith("multirotor") and r["replan"] == r["prediction"]
    with pytest.raises(Conflict, match="cannot replan now: waiting for pack battery voltage"):
        svc.request_replan("operator")
    assert list(svc.state.get("packs")) == ["battery"] and list(svc.state.get("motors")) == ["m1", "m2", "m3", "m4"]
    assert svc.state.get("vehicle")["source"] == "given"
    for t in range(1, 4):
        loop.process(PackFrame(float(t), "battery", 16.4, 8.0, None))
        for m in ("m1", "m2", "m3", "m4"):
            loop.process(MotorFrame(float(t), m, 2.0, 5000.0, 30.0))
    r = svc.state.get("readiness")
    assert r["state"] == "ready" and r["replan"] == "ready" and r["motor_telemetry"] == "ready"
    assert 0.0 <= svc.state.get("packs")["battery"]["soc"] <= 1.0
    # an operator fault names one of the description's motors
    with pytest.raises(ValueError, match="no motor 'aft' on this vehicle; have m1, m2, m3, m4"):
        svc.declare_fault("motor_power_loss", "aft", 0.5, "", replan=False)
    fid = svc.declare_fault("motor_power_loss", "m3", 0.5, "", replan=False)
    loop.process(PackFrame(4.0, "battery", 16.4, 8.0, None))
    assert svc.state.get("motors")["m3"]["health"] == pytest.approx(0.5) and fid


def test_the_paper_aircraft_without_discovery_is_unchanged(tmp_path):
    svc, loop = _loop(tmp_path)
    assert svc.state.get("vehicle")["name"] == "edge540" and svc.state.get("vehicle")["source"] == "default"
    assert loop.estimator.pack_names == ("LLF20", "ULA20", "LRF40", "URA40")
    assert svc.state.get("readiness")["motor_diagnosis"] == "motors on one shaft: their shares of the shaft power"


def test_a_provisional_description_is_adopted_and_said(tmp_path):
    svc, loop = _loop(tmp_path, discover=True)
    assert isinstance(loop.diagnoser, AwaitingVehicle) and not loop.estimator.ready()
    assert svc.state.get("vehicle")["source"] == "deriving"
    assert svc.state.get("readiness")["state"] == "waiting for the vehicle description: the vehicle's HEARTBEAT"
    with pytest.raises(Conflict, match="waiting for the vehicle description"):
        svc.request_replan("operator")
    obs = ProvisionalObserver()
    obs.observe("HEARTBEAT", {"type": 2, "autopilot": 3})
    for _ in range(5):
        obs.observe("BATTERY_STATUS", {"id": 0, "voltages": [4150] * 4 + [65535] * 6, "temperature": 32767,
                                       "battery_remaining": 90, "current_consumed": 10, "current_battery": 50})
        obs.observe("ESC_TELEMETRY_1_TO_4", {"current": [100, 110, 90, 100], "rpm": [5000] * 4,
                                             "temperature": [30] * 4})
    # no capacity parameter yet and no discharge: waited for, said, never guessed
    assert obs.waiting_for().startswith("the capacity of battery0 (unknown: no BATT_CAPACITY/BAT1_CAPACITY")
    obs.observe("PARAM_VALUE", {"param_id": "BATT_CAPACITY", "param_value": 5200.0})
    assert obs.waiting_for() is None
    desc, notes = obs.derive()
    assert desc.packs[0].capacity_mah == 5200.0 and any("BATT_CAPACITY parameter" in n for n in notes)
    loop.adopt_vehicle(desc, notes)
    about = svc.state.get("vehicle")
    assert about["source"] == "provisional" and about["provisional"] and about["packs"] == ["battery0"]
    assert any("capacity 5200 mAh from the autopilot's BATT_CAPACITY parameter" in n for n in about["notes"])
    assert about["motors"] == ["esc0", "esc1", "esc2", "esc3"] and "vehicle init --from LOG" in about["save"]
    assert [e for e in svc.events.since(0) if e.kind == "vehicle" and e.data["source"] == "provisional"]
    assert loop.estimator.pack_names == ("battery0",) and loop.telemetry.estimator is loop.estimator
    assert loop.faults.diagnoser is loop.diagnoser and loop.executor.diagnoser is loop.diagnoser
    assert loop.link.mapper.mapping == frame_mapping(desc)
    assert svc.state.get("readiness")["state"].startswith("waiting for pack battery0 voltage")


def test_observer_says_what_it_waits_for():
    obs = ProvisionalObserver()
    assert obs.waiting_for() == "the vehicle's HEARTBEAT"
    obs.observe("HEARTBEAT", {"type": 1, "autopilot": 3})
    assert obs.waiting_for() == "a BATTERY_STATUS with a voltage"
    obs.observe("BATTERY_STATUS", {"id": 1, "voltages": [4200, 4200, 4200] + [65535] * 7})
    assert obs.waiting_for() == "the first voltage readings of battery1 (1 of 5 readings)"


def test_remap_keeps_the_lock_and_swaps_the_rules():
    desc = PRESETS["plane-3s"]
    mapper = FrameMapper(waiting_mapping(), target_system=1)
    assert "BATTERY_STATUS" not in mapper.mapping and not any(k.startswith("ESC_") for k in mapper.mapping)
    mapper.remap(frame_mapping(desc), envelope(desc))
    assert mapper.mapping["BATTERY_STATUS"][0]["key"]["map"] == {"0": "battery"}
    assert mapper.gate.envelope.pack_voltage_v["battery"][1] > 12.6
