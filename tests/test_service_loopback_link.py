"""The live loop against the simulated vehicle over loopback UDP, with the real link and mission client:

* an upload to a vehicle that stores items as stock ArduPlane does (item 0 home, frame 6 -> 3,
  NaN -> 0, NAV_LAND param4 -> 1) is ``confirmed`` under the rules its HEARTBEAT names;
* a vehicle that goes silent (its clock held: no telemetry, no heartbeat) is declared lost after
  ``link_lost_after_s`` of receive time, and restored on its own when it is heard again.
"""
from __future__ import annotations

import socket
import time

import pytest

from gcs_pdm.service.config import load_config
from gcs_pdm.service.decision import Candidate
from gcs_pdm.service.demo import demo_telemetry, sim_config, table3_mission
from gcs_pdm.service.runtime import Service
from gcs_pdm.service.server import start_mavlink, stop_mavlink
from gcs_pdm.sim.vehicle import SimulatedVehicle


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(cond, what: str, timeout: float = 20.0):
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what}")
        time.sleep(0.05)


@pytest.fixture
def running(tmp_path):
    scenario, mission = table3_mission()
    port = _free_udp_port()
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="loopback-token-0123456789",
                              policy="advise", mavlink_url=f"udpin:127.0.0.1:{port}", link_lost_after_s=1.5,
                              record_tlog=False, vehicle="edge540"))
    svc.load_objectives_scenario(scenario)
    start_mavlink(svc)
    held = {"on": False}
    vehicle = SimulatedVehicle(sim_config(scenario, mission), f"udpout:127.0.0.1:{port}", speedup=2.0,
                               telemetry=demo_telemetry(), hold=lambda: held["on"]).start()
    try:
        _wait(lambda: svc.loop.mission_items, "the vehicle's mission read")
        _wait(lambda: svc.state.get("link")["state"] == "up", "link up")
        yield svc, vehicle, held
    finally:
        vehicle.stop()
        stop_mavlink(svc)
        svc.close()


def test_an_upload_to_an_arduplane_storing_vehicle_is_confirmed(running):
    from gcs_pdm.planning.mission import plan_to_mission
    from gcs_pdm.planning.plan import make_plan
    from gcs_pdm.planning.simulator import VehicleSimulator, original_order
    from gcs_pdm.planning.table3_scenario import preflight_scenario
    from gcs_pdm.sim.truth import true_parameters

    svc, vehicle, _ = running
    vehicle.call(lambda core: setattr(core.missions, "store_like_arduplane", True))
    sc = preflight_scenario(10)
    new = plan_to_mission(sc, make_plan(VehicleSimulator.for_scenario(sc, true_parameters()),
                                        list(reversed(original_order(sc))), "reversed"), airborne=True)
    pid = svc.store.add_plan({"items": [], "chosen": {}}, "test", "approved", 0.0)
    ok = svc.loop.upload(pid, list(new.items), Candidate("planner", (10, 9), True, 1.0, 1.0, 1.0), None,
                         new.current_seq)
    up = svc.store.uploads()[0]
    assert ok and up["status"] == "confirmed", up
    assert "ArduPilot (Plane)" in up["readback"]
    assert any(i.frame == 3 for i in svc.loop.mission_items)  # the vehicle's normalised form is what is held


def test_a_silent_vehicle_is_lost_then_restored_over_udp(running):
    svc, vehicle, held = running
    held["on"] = True  # the vehicle stops sending anything
    t0 = time.monotonic()
    _wait(lambda: svc.state.get("link")["state"] == "lost", "link lost", timeout=10.0)
    assert time.monotonic() - t0 >= 1.0  # not before link_lost_after_s of silence
    assert "no heartbeat from vehicle 1" in svc.state.get("link")["reason"]
    held["on"] = False
    _wait(lambda: svc.state.get("link")["state"] == "up", "link restored", timeout=10.0)
    statuses = [e.data.get("status") for e in svc.events.since(0) if e.kind == "link"]
    assert statuses[-2:] == ["lost", "restored"], statuses
