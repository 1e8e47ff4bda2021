"""Flights as records: where one begins and ends (pure), and the service's flights across a restart:
no fault of flight 1 is active in flight 2 (the issue's motor fault "since t=623 s" shown on a new
flight at t=139 s), while it stays in flight 1's history; the operator carries one over explicitly."""
from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, Fault
from gcs_pdm.frames import StatusFrame
from gcs_pdm.packs.flights import FlightBoundaries, split_flights
from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.live import LiveLoop
from gcs_pdm.service.runtime import Service
from gcs_pdm.service.storage import Store
from service_stand_ins import FakeLink, NoMissions  # tests/service_stand_ins.py

TOKEN = "flights-test-token-0123456789"


# --- pure boundaries ------------------------------------------------------------------------------

def kinds(bs):
    return [(b.kind, b.time_s) for b in bs]


def test_arming_begins_and_disarming_ends_a_flight():
    fb = FlightBoundaries(300.0)
    assert fb.observe(0.0, False) == []
    assert kinds(fb.observe(1.0, True)) == [("begin", 1.0)]
    assert fb.observe(2.0, True) == []
    end = fb.observe(3.0, False)
    assert kinds(end) == [("end", 3.0)] and end[0].reason == "disarmed"
    assert fb.observe(4.0, None) == []


def test_message_time_going_back_is_a_reboot_that_ends_and_begins():
    fb = FlightBoundaries(300.0)
    fb.observe(600.0, True)
    bs = fb.observe(10.0, True)
    assert kinds(bs) == [("end", 600.0), ("begin", 10.0)]
    assert "reboot" in bs[0].reason
    # jitter of a second between two links' stamps is not a reboot
    assert fb.observe(9.5, True) == []


def test_a_silence_longer_than_the_setting_ends_the_flight():
    fb = FlightBoundaries(60.0)
    fb.observe(0.0, True)
    fb.observe(100.0, True)
    bs = fb.observe(200.0, True)
    assert kinds(bs) == [("end", 100.0), ("begin", 200.0)]
    assert "link lost for 100 s" in bs[0].reason


def test_a_restored_open_flight_goes_on_when_the_clock_does():
    fb = FlightBoundaries(300.0, open_until_s=700.0)
    assert fb.observe(705.0, True) == []
    assert kinds(fb.observe(706.0, False)) == [("end", 706.0)]


def test_split_flights_of_a_log():
    t = list(range(10))
    armed = [False, True, True, False, False, True, True, True, False, True]
    assert [(a, b) for a, b, *_ in split_flights(t, armed)] == [(1, 3), (5, 8), (9, 10)]


# --- the service across a restart -----------------------------------------------------------------


def make_service(tmp_path):
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, vehicle="edge540"))
    loop = LiveLoop(svc, FakeLink(), NoMissions())
    svc.attach_loop(loop)
    return svc, loop


def fly(loop, t0, t1, armed=True, fault_from=None):
    """Heartbeats each second; from ``fault_from`` on, the diagnoser reports the aft motor's fault."""
    for t in range(t0, t1 + 1):
        if fault_from is not None and t >= fault_from:
            fault = Fault(MOTOR_POWER_LOSS, "aft", 0.6, float(fault_from), 0.9)
            loop.diagnoser.active_faults = lambda f=fault: [f]
        loop.process(StatusFrame(float(t), armed, "AUTO", 4))


@pytest.mark.parametrize("second_clock", ["rebooted", "same clock, disarmed and armed again"])
def test_after_a_restart_and_a_second_flight_no_fault_of_flight_1_is_active(tmp_path, second_clock):
    svc, loop = make_service(tmp_path)
    fly(loop, 0, 700, fault_from=623)
    active = svc.store.faults(active_only=True)
    assert [(f["kind"], f["target"], f["flight_id"]) for f in active] == [(MOTOR_POWER_LOSS, "aft", 1)]
    assert svc.state.get("motors")["aft"]["health"] < 1.0
    svc.close()  # the service stops during flight 1 (no disarm heard)

    svc, loop = make_service(tmp_path)
    assert svc.store.open_flight()["id"] == 1
    if second_clock == "rebooted":
        fly(loop, 0, 139)
    else:
        fly(loop, 701, 710)
        fly(loop, 711, 720, armed=False)
        fly(loop, 721, 860)
    try:
        assert svc.store.faults(active_only=True) == []
        assert svc.state.get("motors")["aft"]["health"] == 1.0
        flights = svc.store.flights()
        assert [f["id"] for f in flights] == [2, 1]
        assert flights[0]["open"] and not flights[1]["open"]
        one = svc.store.flight(1)
        assert [(f["kind"], f["active"]) for f in one["faults"]] == [(MOTOR_POWER_LOSS, False)]
        assert ("reboot" in one["end_reason"]) == (second_clock == "rebooted")
        client = TestClient(create_app(svc))
        assert [f["id"] for f in client.get("/flights").json()] == [2, 1]
        assert client.get("/flights/1").json()["faults"][0]["detail"]["time_s"] == 623.0
        assert client.get("/faults", params={"active": True}).json() == []
        assert client.get("/flights/9").status_code == 404
        # the operator carries the damaged motor over, explicitly
        fault_id = one["faults"][0]["id"]
        r = client.post("/flights/carry-over", json={"fault_id": fault_id, "note": "motor not replaced"},
                        headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 201, r.text
        carried = r.json()
        assert carried["flight_id"] == 2 and carried["active"] and carried["target"] == "aft"
        assert f"carried over from flight 1 (fault {fault_id})" in carried["detail"]["note"]
        assert client.post("/flights/carry-over", json={"fault_id": fault_id}).status_code == 401
    finally:
        svc.close()


def test_a_ground_fault_declared_before_arming_joins_the_flight(tmp_path):
    svc, loop = make_service(tmp_path)
    try:
        fly(loop, 0, 5, armed=False)
        fid = svc.declare_fault(MOTOR_POWER_LOSS, "fwd", 0.3, "prop chipped", replan=False)
        fly(loop, 6, 20)
        active = svc.store.faults(active_only=True)
        assert [(f["id"], f["flight_id"]) for f in active] == [(fid, 1)]
        fly(loop, 21, 25, armed=False)
        assert svc.store.faults(active_only=True) == []
    finally:
        svc.close()


def test_an_old_database_gains_flights_and_keeps_its_rows(tmp_path):
    import sqlite3

    path = tmp_path / "old.sqlite3"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
    db.execute("INSERT INTO meta VALUES('schema_version', '1')")
    db.execute("""CREATE TABLE faults (id INTEGER PRIMARY KEY AUTOINCREMENT, time_s REAL, kind TEXT NOT NULL,
                  target TEXT, magnitude REAL, source TEXT NOT NULL, active INTEGER NOT NULL, body TEXT NOT NULL,
                  created_at REAL NOT NULL)""")
    db.execute("INSERT INTO faults(time_s, kind, target, magnitude, source, active, body, created_at) "
               "VALUES(623, 'motor_power_loss', 'aft', 0.6, 'diagnoser', 1, '{}', 1.0)")
    db.commit()
    db.close()
    store = Store(path)
    try:
        assert store.schema_version == 2
        f, = store.faults()
        assert f["active"] and f["flight_id"] is None
        fid, closed, carried = store.begin_flight(0.0, "armed")
        assert closed == [f["id"]] and carried == [] and store.faults(active_only=True) == []
    finally:
        store.close()
