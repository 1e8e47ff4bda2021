"""The link's state: a vehicle silent for ``link_lost_after_s`` is declared lost everywhere (live
state, /status, /health, an event), predictions stop counting down, replans, approvals, reverts and
uploads are refused with a 409, and all of it recovers on its own when the vehicle is heard again.

The vehicle's silence is the link's ``vehicle_silent_s()`` (receive time), scripted here."""
from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from gcs_pdm import missions as M
from gcs_pdm.planning.table3_scenario import preflight_scenario
from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.decision import Candidate
from gcs_pdm.service.live import LinkLost, LiveLoop
from gcs_pdm.service.runtime import Service
from test_service_live_loop import FakeLink, FakeVehicleMissions, _new_mission, original_mission

TOKEN = "link-state-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class SilentLink(FakeLink):
    """A link whose vehicle's silence (wall seconds since its last heartbeat) the test sets."""

    def __init__(self):
        super().__init__()
        self.silent: float | None = None

    def vehicle_silent_s(self, now=None):
        return self.silent


class CountingVehicle(FakeVehicleMissions):
    def __init__(self, items):
        super().__init__(items)
        self.attempts = 0

    def upload(self, items):
        self.attempts += 1
        return super().upload(items)


def _wait(cond, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.05)
    return cond()


@pytest.fixture
def setup(tmp_path):
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, policy="advise",
                              link_lost_after_s=3.0))
    svc.load_objectives_scenario(preflight_scenario(10))
    link = SilentLink()
    vehicle = CountingVehicle(original_mission().items)
    loop = LiveLoop(svc, link, vehicle)
    svc.attach_loop(loop)
    loop.start()
    assert _wait(lambda: loop.mission_items is not None)
    yield svc, loop, link, vehicle, TestClient(create_app(svc))
    svc.close()


def _proposal(svc) -> int:
    new = _new_mission()
    chosen = {"name": "planner", "route": [10, 9], "feasible": True, "reward": 1.0, "reward_reached": 1.0,
              "objective": 1.0}
    return svc.store.add_plan({"items": [M.item_to_json(i) for i in new.items], "chosen": chosen,
                               "current_seq": new.current_seq}, "test", "proposed", 1.0)


def test_a_silent_vehicle_is_lost_everywhere_refused_and_recovers_on_its_own(setup):
    svc, loop, link, vehicle, client = setup
    link.silent = 0.5  # heard half a second ago
    svc.state.update_nested("packs", "LLF20", time_to_cutoff_s=600.0, time_to_cutoff_sd=30.0)
    time.sleep(0.5)
    assert client.get("/health").json()["status"] == "ok"
    pid = _proposal(svc)

    link.silent = 3.5  # past link_lost_after_s
    assert _wait(lambda: client.get("/status").json()["link"]["state"] == "lost")
    status = client.get("/status").json()
    assert status["link"]["connected"] is False and "no heartbeat from vehicle 1" in status["link"]["reason"]
    # no count-down for a vehicle nobody hears
    assert status["packs"]["LLF20"]["time_to_cutoff_s"] is None and status["prediction"]["stale"] is True
    health = client.get("/health").json()
    assert health["status"] == "degraded" and health["link_connected"] is False
    assert any("link lost" in r for r in health["reasons"])
    lost = [e for e in svc.events.since(0) if e.kind == "link" and e.data.get("status") == "lost"]
    assert len(lost) == 1 and "no heartbeat" in lost[0].data["reason"]

    # refused with a clear 409, and nothing reaches the vehicle
    for path in ("/missions/replan", f"/missions/plans/{pid}/approve", "/missions/refresh"):
        r = client.post(path, headers=AUTH)
        assert r.status_code == 409 and "link lost" in r.json()["detail"], (path, r.text)
    assert svc.store.plan(pid)["status"] == "proposed"
    with pytest.raises(LinkLost):
        svc.request_replan("operator")
    # an upload already queued when the link went is not attempted (no minutes of retries)
    out = loop.executor.upload(pid, list(_new_mission().items), Candidate("planner", (10, 9), True, 1.0, 1.0, 1.0),
                               None)
    assert out.record_status == "failed" and vehicle.attempts == 0
    assert "link lost" in svc.store.uploads()[0]["error"]
    # an internal trigger while lost waits for the vehicle instead of planning on a stale state
    loop.request_replan("fault: test")
    time.sleep(0.3)
    assert loop.executor.busy is False

    link.silent = 0.2  # the vehicle is back
    assert _wait(lambda: client.get("/health").json()["status"] == "ok")
    status = client.get("/status").json()
    assert status["link"]["state"] == "up" and status["link"]["connected"] is True and status["link"]["reason"] is None
    assert [e.data["status"] for e in svc.events.since(0) if e.kind == "link"][-2:] == ["lost", "restored"]
    assert not svc.store.plans(status="approved")
    pid2 = _proposal(svc)
    r = client.post(f"/missions/plans/{pid2}/approve", headers=AUTH)
    assert r.status_code == 200, r.text
    assert _wait(lambda: vehicle.attempts == 1)
    assert _wait(lambda: svc.store.plan(pid2)["status"] == "uploaded")


def test_a_vehicle_never_heard_is_waiting_not_lost(setup):
    svc, loop, link, vehicle, client = setup
    time.sleep(0.5)
    assert link.silent is None
    assert client.get("/status").json()["link"]["state"] == "waiting"
    assert client.get("/health").json()["status"] == "ok"
    loop.require_link("replan")  # no refusal: only a vehicle that went silent is lost
