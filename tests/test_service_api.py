"""HTTP API: every endpoint, auth (401), validation (422 naming the field), persistence across a restart."""
from __future__ import annotations

import json
import time

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.runtime import Service

TOKEN = "api-test-token-0123456789"


@pytest.fixture
def service(tmp_path):
    cfg = load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, policy="advise")
    svc = Service(cfg)
    yield svc
    svc.close()


@pytest.fixture
def client(service):
    return TestClient(create_app(service))


AUTH = {"Authorization": f"Bearer {TOKEN}"}


def fields_of(resp) -> list[str]:
    return [".".join(str(x) for x in d["loc"]) for d in resp.json()["detail"]]


def test_health_and_status(client):
    h = client.get("/health").json()
    assert h["status"] == "ok" and h["policy"] == "advise" and h["active_parameter_set"] == "paper_si"
    s = client.get("/status").json()
    assert set(s["packs"]) == {"LLF20", "ULA20", "LRF40", "URA40"} and set(s["motors"]) == {"fwd", "aft"}
    assert s["link"]["connected"] is False
    assert "gcs-pdm" in client.get("/").text
    assert "/jobs/fit" in client.get("/openapi.json").json()["paths"]


@pytest.mark.parametrize("method,path,body", [
    ("post", "/faults", {"motor": "aft", "magnitude": 0.5}),
    ("post", "/faults/1/clear", None),
    ("post", "/missions/plans/1/approve", None),
    ("post", "/missions/plans/1/reject", None),
    ("post", "/missions/replan", None),
    ("post", "/missions/refresh", None),
    ("post", "/missions/uploads/1/revert", None),
    ("put", "/policy", {"policy": "auto"}),
    ("post", "/parameter-sets", {"parameter_set": {}}),
    ("post", "/parameter-sets/paper_si/activate", None),
    ("post", "/jobs/fit", {}),
    ("post", "/jobs/abc/cancel", None),
])
def test_mutations_need_the_token(client, method, path, body):
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "Basic " + TOKEN}):
        r = getattr(client, method)(path, json=body, headers=headers) if body is not None else \
            getattr(client, method)(path, headers=headers)
        assert r.status_code == 401, (path, headers, r.text)
        assert r.headers.get("www-authenticate") == "Bearer"


def test_upload_needs_the_token(client):
    r = client.post("/files", files={"file": ("a.csv", b"t,v\n0,1\n")})
    assert r.status_code == 401


def test_faults_declare_list_clear(client, service):
    r = client.post("/faults", json={"motor": "aft", "magnitude": 1.5}, headers=AUTH)
    assert r.status_code == 422 and "body.magnitude" in fields_of(r)
    r = client.post("/faults", json={"motor": "middle", "magnitude": 0.5}, headers=AUTH)
    assert r.status_code == 422 and "body.motor" in fields_of(r)
    r = client.post("/faults", json={"motor": "aft", "magnitude": 0.6, "note": "smoke"}, headers=AUTH)
    assert r.status_code == 201
    f = r.json()
    assert f["source"] == "operator" and f["target"] == "aft" and f["magnitude"] == 0.6 and f["active"]
    assert [x["id"] for x in client.get("/faults?active=true").json()] == [f["id"]]
    assert client.post(f"/faults/{f['id']}/clear", headers=AUTH).json()["active"] is False
    assert client.get("/faults?active=true").json() == []
    assert client.post("/faults/999/clear", headers=AUTH).status_code == 404
    kinds = [e["kind"] for e in client.get("/events/poll?since=0").json()]
    assert kinds.count("fault") == 2


def test_missions_without_a_link(client, service):
    assert client.get("/missions/current").json() == {"items": None, "source": "none", "time_s": None, "waypoints": None}
    assert client.get("/missions/proposed").json() == []
    item = {"seq": 0, "frame": 6, "command": 16, "current": 1, "autocontinue": 1, "param1": 0.0, "param2": 0.0,
            "param3": 0.0, "param4": None, "x": 370870000, "y": -763800000, "z": 100.0, "mission_type": 0}
    pid = service.store.add_plan({"items": [item], "chosen": {"name": "planner", "route": [1]}}, "test", "proposed", 12.0)
    assert [p["id"] for p in client.get("/missions/proposed").json()] == [pid]
    assert client.get(f"/missions/plans/{pid}").json()["items"][0]["param4"] is None
    # approving needs a vehicle to upload to
    r = client.post(f"/missions/plans/{pid}/approve", headers=AUTH)
    assert r.status_code == 409 and "no vehicle link" in r.json()["detail"]
    r = client.post(f"/missions/plans/{pid}/reject", json={"note": "too far"}, headers=AUTH)
    assert r.status_code == 200 and r.json()["status"] == "rejected"
    assert r.json()["history"][-1]["note"] == "too far"
    assert client.post(f"/missions/plans/{pid}/reject", headers=AUTH).status_code == 409
    assert client.get("/missions/plans/12345").status_code == 404
    assert [p["id"] for p in client.get("/missions/history").json()] == [pid]
    assert client.get("/missions/uploads").json() == []
    assert client.post("/missions/replan", headers=AUTH).status_code == 409
    assert client.post("/missions/refresh", headers=AUTH).status_code == 409
    assert client.post("/missions/uploads/7/revert", headers=AUTH).status_code == 404
    uid = service.store.add_upload(pid, "confirmed", {"items": [item], "previous_items": [item]})
    r = client.post(f"/missions/uploads/{uid}/revert", headers=AUTH)
    assert r.status_code == 409 and "no vehicle link" in r.json()["detail"]


def test_policy(client):
    assert client.get("/policy").json() == {"policy": "advise"}
    r = client.put("/policy", json={"policy": "sometimes"}, headers=AUTH)
    assert r.status_code == 422 and "body.policy" in fields_of(r)
    assert client.put("/policy", json={"policy": "auto"}, headers=AUTH).json() == {"policy": "auto"}
    assert client.get("/health").json()["policy"] == "auto"


def test_parameter_sets_list_get_import_export_activate(client):
    names = {p["name"] for p in client.get("/parameter-sets").json()}
    assert {"paper", "previous", "paper_si", "previous_si"} <= names
    exported = client.get("/parameter-sets/previous_si").json()
    assert exported["name"] == "previous_si" and "LLF20" in exported["packs"]
    assert client.get("/parameter-sets/nope").status_code == 404
    # import under a new name, with a changed value
    exported["packs"]["LLF20"]["battery"]["R_s"] = 0.009
    r = client.post("/parameter-sets", json={"parameter_set": exported, "name": "bench_1"}, headers=AUTH)
    assert r.status_code == 201 and r.json()["provenance"]["source"] == "import"
    assert client.get("/parameter-sets/bench_1").json()["packs"]["LLF20"]["battery"]["R_s"] == 0.009
    # same name again: conflict unless overwrite; built-ins are never overwritten
    assert client.post("/parameter-sets", json={"parameter_set": exported, "name": "bench_1"}, headers=AUTH).status_code == 409
    assert client.post("/parameter-sets", json={"parameter_set": exported, "name": "bench_1", "overwrite": True},
                       headers=AUTH).status_code == 201
    assert client.post("/parameter-sets", json={"parameter_set": exported, "name": "paper_si", "overwrite": True},
                       headers=AUTH).status_code == 409
    # a bad value names its field
    exported["packs"]["ULA20"]["battery"]["C_b"] = -3.0
    r = client.post("/parameter-sets", json={"parameter_set": exported, "name": "bad"}, headers=AUTH)
    assert r.status_code == 422 and any("ULA20" in f and "C_b" in f for f in fields_of(r)), r.json()
    r = client.post("/parameter-sets", json={"parameter_set": exported, "name": "bad name!"}, headers=AUTH)
    assert r.status_code == 422 and "body.name" in fields_of(r)
    # activation; the verbatim 'paper' set cannot be flown
    assert client.post("/parameter-sets/bench_1/activate", headers=AUTH).json()["active"] is True
    assert client.get("/health").json()["active_parameter_set"] == "bench_1"
    assert client.post("/parameter-sets/paper/activate", headers=AUTH).status_code == 409
    assert client.post("/parameter-sets/none/activate", headers=AUTH).status_code == 404


def test_files_and_tlogs(client, service):
    r = client.post("/files", files={"file": ("flight.txt", b"x")}, headers=AUTH)
    assert r.status_code == 422 and "body.file" in fields_of(r)
    r = client.post("/files", files={"file": ("empty.csv", b"")}, headers=AUTH)
    assert r.status_code == 422
    r = client.post("/files", files={"file": ("f1.csv", GOOD_CSV)}, headers=AUTH)
    assert r.status_code == 201 and r.json()["kind"] == "csv" and r.json()["size_bytes"] > 0
    tlog = _tlog_bytes()
    r = client.post("/files", files={"file": ("../../evil.tlog", tlog)}, headers=AUTH)
    assert r.status_code == 201 and r.json()["filename"] == "evil.tlog"
    assert len(client.get("/files").json()) == 2
    tl = client.get("/tlogs").json()
    assert len(tl) == 1 and tl[0]["size_bytes"] == len(tlog)
    # relative to the data directory: no server path is shown
    assert not tl[0]["path"].startswith("/") and (service.config.data_path / tl[0]["path"]).is_file()


GOOD_CSV = b"time_s,current_a,voltage_v,temperature_c,ambient_c\n0,10,20.1,25,20\n1,10,20.0,25.1,20\n"


def _tlog_bytes() -> bytes:
    import struct

    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = b""
    for k in range(3):
        pkt = mav.heartbeat_encode(1, 3, 0, 0, 4).pack(mav)
        out += struct.pack(">Q", 1_700_000_000_000_000 + k * 1_000_000) + pkt
    return out


def test_garbage_flight_files_are_rejected_and_not_indexed(client, service):
    for name, data in (("junk.tlog", b"\x00" * 16), ("junk.tlog", b"hello world, not mavlink" * 10),
                       ("f1.csv", b"time_s,LLF20_voltage_v\n0,20.1\n"), ("bin.csv", b"\x89PNG\r\n\x1a\n\x00\x00"),
                       ("junk.parquet", b"not parquet at all")):
        r = client.post("/files", files={"file": (name, data)}, headers=AUTH)
        assert r.status_code == 422 and "body.file" in fields_of(r), (name, r.text)
    assert client.get("/files").json() == [] and client.get("/tlogs").json() == []


def test_bad_last_event_id_is_not_a_server_error(client, service):
    service.events.publish("policy", policy="auto")
    with client.stream("GET", "/events", headers={"Last-Event-ID": "abc"}) as r:
        assert r.status_code == 200
        first = next(r.iter_lines())
        assert first.startswith(":")


def test_fit_settings_are_validated_up_front(client, service):
    fid = client.post("/files", files={"file": ("f1.csv", GOOD_CSV)}, headers=AUTH).json()["id"]
    flights = {"train": [{"file_id": fid}], "validation": [{"file_id": fid}]}
    for settings, field in (({"sa_starts": 3}, "body.settings.sa_starts"),
                            ({"search": {"sa_starts": 3}}, "body.settings.search.sa_starts"),
                            ({"search": {"starts": "many"}}, "body.settings.search.starts"),
                            ({"workers": 1.5}, "body.settings.workers"),
                            ({"base": "paper_si"}, "body.settings.base"),
                            ({"cleaning": 3}, "body.settings.cleaning"),
                            ({"reference": "nope"}, "body.settings.reference")):
        r = client.post("/jobs/fit", json={"flights": flights, "settings": settings}, headers=AUTH)
        assert r.status_code == 422 and field in fields_of(r), (settings, r.text)
    assert client.get("/jobs").json() == []


def test_a_directory_is_not_a_flight_file(client, service):
    (service.config.data_path / "adir.csv").mkdir()
    ref = {"path": str(service.config.data_path / "adir.csv")}
    r = client.post("/jobs/fit", json={"flights": {"train": [ref], "validation": [ref]}}, headers=AUTH)
    assert r.status_code == 422 and "body.flights.train.0" in fields_of(r)


def test_fit_job_validation(client, service):
    r = client.post("/jobs/fit", json={"flights": {"train": [], "validation": [{"file_id": "x"}]}}, headers=AUTH)
    assert r.status_code == 422 and "body.flights.train" in fields_of(r)
    r = client.post("/jobs/fit", json={"flights": {"train": [{"file_id": "x", "tlog_id": 1}],
                                                   "validation": [{"file_id": "y"}]}}, headers=AUTH)
    assert r.status_code == 422 and any(f.startswith("body.flights.train.0") for f in fields_of(r))
    r = client.post("/jobs/fit", json={"flights": {"train": [{"file_id": "nope"}], "validation": [{"file_id": "y"}]}},
                    headers=AUTH)
    assert r.status_code == 422 and "body.flights.train.0" in fields_of(r)
    r = client.post("/jobs/fit", json={"packs": ["XX"], "flights": {"train": [{"file_id": "a"}],
                                                                    "validation": [{"file_id": "b"}]}}, headers=AUTH)
    assert r.status_code == 422 and "body.packs.0" in fields_of(r)
    r = client.post("/jobs/fit", json={"base_set": "nope", "flights": {"train": [{"path": "/etc/passwd"}],
                                                                       "validation": [{"path": "/etc/passwd"}]}},
                    headers=AUTH)
    assert r.status_code == 422 and "body.base_set" in fields_of(r)
    r = client.post("/jobs/fit", json={"flights": {"train": [{"path": "/etc/passwd"}], "validation": [{"path": "/etc/passwd"}]}},
                    headers=AUTH)
    assert r.status_code == 422 and "outside the data directory" in r.json()["detail"][0]["msg"]


def test_jobs_progress_cancel_and_result(client, service):
    import threading

    gate = threading.Event()

    def slow(request, progress, should_stop):
        for i in range(200):
            if should_stop():
                return {"stopped_at": i}
            progress(i / 200, "working")
            gate.wait(0.01)
        return {"value": request["x"] * 2}

    service.runner.register("slow", slow)
    done = service.runner.submit("slow", {"x": 21})
    assert service.runner.wait(done, timeout=20)["status"] == "succeeded"
    j = client.get(f"/jobs/{done}").json()
    assert j["progress"] == 1.0 and j["stage"] == "done"
    assert client.get(f"/jobs/{done}/result").json() == {"value": 42}
    victim = service.runner.submit("slow", {"x": 1})
    for _ in range(200):
        if client.get(f"/jobs/{victim}").json()["status"] == "running":
            break
        time.sleep(0.01)
    r = client.post(f"/jobs/{victim}/cancel", headers=AUTH)
    assert r.status_code == 200
    assert service.runner.wait(victim, timeout=20)["status"] == "cancelled"
    assert client.get(f"/jobs/{victim}/result").status_code == 409
    assert client.get("/jobs/nope").status_code == 404
    assert client.post("/jobs/nope/cancel", headers=AUTH).status_code == 404
    assert {j["id"] for j in client.get("/jobs").json()} == {done, victim}
    assert client.get(f"/jobs/{done}/plots/fit").status_code == 404
    statuses = [e["data"]["status"] for e in client.get("/events/poll?since=0").json() if e["kind"] == "job"]
    assert "running" in statuses and "succeeded" in statuses and "cancelled" in statuses


def test_failing_job_is_recorded(service):
    def broken(request, progress, should_stop):
        raise ValueError("flight 3: no voltage column")

    service.runner.register("broken", broken)
    j = service.runner.wait(service.runner.submit("broken", {}), timeout=10)
    assert j["status"] == "failed" and "no voltage column" in j["error"]


def test_fit_job_survives_restart_as_interrupted(tmp_path):
    cfg = load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN)
    svc = Service(cfg)
    import threading

    started = threading.Event()
    release = threading.Event()

    def fit_like(request, progress, should_stop):
        progress(0.3, "annealing start 3/10")
        started.set()
        release.wait(30)
        return {}

    svc.runner.register("fit", fit_like)
    job_id = svc.runner.submit("fit", {"component": "battery", "packs": ["LLF20"]})
    assert started.wait(10)
    # The process "dies": the database is left as it was while the job ran.
    svc.store.close()
    release.set()
    # A new process on the same database.
    svc2 = Service(cfg)
    try:
        client = TestClient(create_app(svc2))
        j = client.get(f"/jobs/{job_id}").json()
        assert j["status"] == "interrupted" and j["progress"] == pytest.approx(0.3)
        assert j["stage"].startswith("annealing") and j["request"]["packs"] == ["LLF20"]
        assert "stopped" in j["error"]
        assert client.get("/health").json()["interrupted_jobs_at_start"] == 1
    finally:
        svc2.close()


def test_sse_stream_delivers_events(client, service):
    service.events.publish("fault", kind="motor_power_loss", target="aft", magnitude=0.7)
    with client.stream("GET", "/events?since=0") as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        text = ""
        for chunk in r.iter_text():
            text += chunk
            if "event: fault" in text and "\n\n" in text.split("event: fault", 1)[1]:
                break
    payload = json.loads(text.split("event: fault", 1)[1].split("data: ", 1)[1].split("\n", 1)[0])
    assert payload["data"]["target"] == "aft" and payload["kind"] == "fault"


def test_fit_save_as_is_checked_up_front(client, service):
    from gcs_pdm.service.fit_jobs import check_save_as

    fid = client.post("/files", files={"file": ("f1.csv", GOOD_CSV)}, headers=AUTH).json()["id"]
    flights = {"train": [{"file_id": fid}], "validation": [{"file_id": fid}]}
    exported = client.get("/parameter-sets/previous_si").json()
    for name in ("mine", "flying"):
        assert client.post("/parameter-sets", json={"parameter_set": exported, "name": name},
                           headers=AUTH).status_code == 201
    assert client.post("/parameter-sets/flying/activate", headers=AUTH).status_code == 200
    for save_as, overwrite in (("paper_si", True), ("flying", True), ("mine", False)):
        r = client.post("/jobs/fit", json={"flights": flights, "save_as": save_as, "overwrite": overwrite},
                        headers=AUTH)
        assert r.status_code == 422 and "body.save_as" in fields_of(r), (save_as, r.text)
    assert client.get("/jobs").json() == []
    # an existing user set that is not active may be replaced when asked to; a new name always
    assert check_save_as(service, "mine", True) is None and check_save_as(service, "new_one") is None


def test_activation_says_what_it_changes(client, service):
    exported = client.get("/parameter-sets/previous_si").json()
    assert client.post("/parameter-sets", json={"parameter_set": exported, "name": "bench_2"},
                       headers=AUTH).status_code == 201
    assert client.post("/parameter-sets/bench_2/activate", headers=AUTH).status_code == 200
    ev = [e for e in client.get("/events/poll?since=0").json() if e["kind"] == "parameter_set"][-1]
    assert "next replan" in ev["data"]["applies_to"] and "next service start" in ev["data"]["applies_to"]
