"""``/packs`` over HTTP and the console's pack page: the packs a service knows (here ingested from
synthetic tlogs into its database), one pack's trend and forecast, slot assignments with the token;
and a live flight's health point, made from the pack telemetry heard around it."""
from __future__ import annotations

import math

from fastapi.testclient import TestClient

from gcs_pdm.packs.ingest import IngestSettings, run_ingest
from gcs_pdm.packs.synthetic import SyntheticPack, write_pack_tlog
from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.live import LiveLoop
from gcs_pdm.service.runtime import Service
from service_stand_ins import FakeLink, NoMissions, fly_rested_pack  # tests/service_stand_ins.py

TOKEN = "packs-api-test-token-0123456789"


AUTH = {"Authorization": f"Bearer {TOKEN}"}


def service(tmp_path, **kw):
    return Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, **kw))


def test_packs_over_http_with_trend_and_assignments(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    # one pack losing 2 % a flight and gaining resistance: enough points for a trend and a forecast
    for k in range(8):
        write_pack_tlog(logs / f"f{k}.tlog", SyntheticPack(serial="PK-7", capacity_ah=5.0 * (1 - 0.02 * k),
                                                           resistance_ohm=0.02 * (1 + 0.05 * k)),
                        epoch_s=1.7e9 + 86400 * k, seed=k, bulk=False)
    svc = service(tmp_path)
    try:
        run_ingest(sorted(logs.glob("*.tlog")), IngestSettings(), workers=1, known=svc.packs.known_log,
                   on_result=svc.packs.add_log_result)
        client = TestClient(create_app(svc))
        packs = client.get("/packs").json()
        assert [p["pack_id"] for p in packs] == ["PK-7"] and packs[0]["flights"] == 8
        pack = client.get("/packs/PK-7").json()
        caps = [h["capacity_ah"] for h in pack["history"]]
        assert caps[0] > caps[-1] and abs(caps[-1] / (5.0 * 0.86) - 1) < 0.03
        t = pack["trend"]
        assert t["capacity_fit"]["points"] == 8
        f = t["capacity_forecast"]
        # 2 % per flight of ~0.47 equivalent cycles: 80 % near 10 flights, ~4.7 cycles
        assert f["cycles"] is not None and 3.0 < f["cycles"] < 7.0 and f["low"] <= f["cycles"] <= (f["high"] or math.inf)
        assert pack["thresholds"] == {"capacity_fraction": 0.8, "resistance_factor": 1.5}
        assert client.get("/packs/nope").status_code == 404
        body = {"slot": "battery0", "pack_id": "P-17"}
        assert client.put("/packs/assignments", json=body).status_code == 401
        r = client.put("/packs/assignments", json=body, headers=AUTH)
        assert r.status_code == 200 and r.json()["pack_id"] == "P-17"
        assert client.get("/packs/assignments").json()["battery0"]["pack_id"] == "P-17"
        assert client.delete("/packs/assignments/battery0", headers=AUTH).json()["pack_id"] == "P-17"
        assert client.delete("/packs/assignments/battery0", headers=AUTH).status_code == 404
        assert client.get("/packs/assignments").json() == {}
        page = client.get("/console/packs.html")
        assert page.status_code == 200 and "packs.js" in page.text and 'id="slot-priors"' in page.text
        assert client.get("/console/packs.js").status_code == 200
        assert "/console/packs.html" in client.get("/").text
    finally:
        svc.close()


def test_a_live_flight_leaves_a_health_point_for_the_assigned_pack(tmp_path):
    """quad-4s (one 4S pack, 5 Ah in its description): rested, armed, a climb and a cruise, disarmed,
    rested 11 minutes; the operator said pack Q-1 is in the slot."""
    svc = service(tmp_path, vehicle="quad-4s")
    spec = svc.vehicle.packs[0]
    svc.packs.assign(spec.name, "Q-1")
    loop = LiveLoop(svc, FakeLink(), NoMissions())
    svc.attach_loop(loop)
    try:
        cap, r, cells = spec.capacity_mah / 1000.0 * 0.9, 0.03, spec.cells_series
        fly_rested_pack(loop, spec.name, cells, cap, r, until_s=2400.0)
        pack = svc.packs.summary("Q-1")
        h = pack["history"][0]
        assert pack["flights"] == 1 and h["identity"] == "operator assignment" and h["flight_id"] == 1
        assert abs(h["capacity_ah"] / cap - 1.0) < 0.03
        assert abs(h["resistance_25c_ohm"] / r - 1.0) < 0.1
        priors = TestClient(create_app(svc)).get("/packs/priors").json()
        assert priors[spec.name]["capacity_ah"] == h["capacity_ah"] and priors[spec.name]["pack_id"] == "Q-1"
    finally:
        svc.close()
