"""A real fitting job through the HTTP API: uploaded CSV flights → fit_battery → stored set, plots."""
from __future__ import annotations

import io
from pathlib import Path

import pandas as pd
import pytest
from fastapi.testclient import TestClient

from gcs_pdm.fitting.synthetic import generate_flight, synthetic_truth
from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.runtime import Service

TOKEN = "fit-jobs-test-token-0123"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _csv(flight) -> bytes:
    buf = io.StringIO()
    pd.DataFrame({c: getattr(flight, c) for c in flight.columns()}).to_csv(buf, index=False)
    return buf.getvalue().encode()


def _upload_llf20_flights(client) -> list[int]:
    """Three synthetic LLF20 flights uploaded as CSV files: their file ids (train, validation, test)."""
    truth = synthetic_truth(seed=3)
    ids = []
    for seed in range(3):
        f = generate_flight(truth, seed, duration_s=600.0, dt=2.0, damage=None).packs["LLF20"]
        r = client.post("/files", files={"file": (f"flight{seed}.csv", _csv(f))}, headers=AUTH)
        assert r.status_code == 201
        ids.append(r.json()["id"])
    return ids


@pytest.mark.slow
def test_fit_job_from_uploaded_csv(tmp_path):
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN))
    try:
        client = TestClient(create_app(svc))
        ids = _upload_llf20_flights(client)
        body = {"component": "battery", "packs": ["LLF20"], "save_as": "fitted_llf20",
                "flights": {"train": [{"file_id": ids[0]}], "validation": [{"file_id": ids[1]}],
                            "test": [{"file_id": ids[2]}]},
                "settings": {"model": "paper", "search": {"starts": 2, "sa_generations": 8, "lm_max_nfev": 4, "seed": 1},
                             "workers": 1}}
        r = client.post("/jobs/fit", json=body, headers=AUTH)
        assert r.status_code == 202, r.text
        job = svc.runner.wait(r.json()["id"], timeout=240)
        assert job["status"] == "succeeded", job["error"]
        result = client.get(f"/jobs/{job['id']}/result").json()
        fit = result["fits"]["LLF20"]
        assert fit["flights"]["test"] and "overall" in fit["errors"]["learned"]["test"]
        assert result["saved_as"] == "fitted_llf20"
        stored = client.get("/parameter-sets/fitted_llf20").json()
        assert stored["packs"]["LLF20"]["battery"]["R_s"] == pytest.approx(fit["parameters"]["R_s"])
        assert stored["provenance"]["job"] == job["id"]
        plot = next(iter(result["plots"]))
        png = client.get(f"/jobs/{job['id']}/plots/{plot}")
        assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
    finally:
        svc.close()


@pytest.mark.slow
def test_fit_job_from_recorded_tlogs_in_the_index(tmp_path):
    from gcs_pdm.service.demo import sim_config, table3_mission
    from gcs_pdm.sim.record import fly

    scenario, mission = table3_mission()
    (tmp_path / "tlogs").mkdir()
    for seed in range(3):
        cfg = sim_config(scenario, mission, seed)
        fly(cfg, tlog_path=tmp_path / "tlogs" / f"flight{seed}.tlog", max_time_s=400.0)
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN))
    try:
        client = TestClient(create_app(svc))
        tl = client.get("/tlogs").json()
        assert [Path(t["path"]).name for t in tl] == ["flight0.tlog", "flight1.tlog", "flight2.tlog"]
        assert all(t["note"] == "found at start-up" and t["size_bytes"] > 0 for t in tl)
        body = {"component": "motor", "flights": {"train": [{"tlog_id": tl[0]["id"]}],
                                                  "validation": [{"tlog_id": tl[1]["id"]}],
                                                  "test": [{"tlog_id": tl[2]["id"]}]},
                "settings": {"search": {"starts": 2, "sa_generations": 6, "lm_max_nfev": 4}, "workers": 1}}
        r = client.post("/jobs/fit", json=body, headers=AUTH)
        assert r.status_code == 202, r.text
        job = svc.runner.wait(r.json()["id"], timeout=240)
        assert job["status"] == "succeeded", job["error"]
        fit = job["result"]["fits"]["motor"]
        assert fit["component"] == "motor" and fit["flights"]["train"]
        from gcs_pdm.models.kernel import MOTOR_PARAMS

        assert {"C_t", "h"} <= set(fit["learned"]) <= set(MOTOR_PARAMS)
        # the merged set carries the learned motor values
        merged = job["result"]["parameter_set"]["motor"]
        assert all(merged[k] == pytest.approx(fit["parameters"][k]) for k in fit["learned"])
        assert (tmp_path / "jobs" / job["id"] / "result.json").exists()
    finally:
        svc.close()


@pytest.mark.slow
def test_fit_over_a_user_set_keeps_its_fixed_values(tmp_path):
    """The values a fit does not learn (here the motor's R_w and I_0) come from the base set asked
    for, a user's set too — not from paper_si."""
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN))
    try:
        client = TestClient(create_app(svc))
        exported = client.get("/parameter-sets/paper_si").json()
        exported["motor"]["R_w"], exported["motor"]["I_0"] = 0.045, 2.1
        assert client.post("/parameter-sets", json={"parameter_set": exported, "name": "bench_motor"},
                           headers=AUTH).status_code == 201
        truth = synthetic_truth(seed=3)
        ids = []
        for seed in range(3):
            f = generate_flight(truth, seed, duration_s=600.0, dt=2.0, damage=None).motor
            r = client.post("/files", files={"file": (f"motor{seed}.csv", _csv(f))}, headers=AUTH)
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
        body = {"component": "motor", "base_set": "bench_motor",
                "flights": {"train": [{"file_id": ids[0]}], "validation": [{"file_id": ids[1]}],
                            "test": [{"file_id": ids[2]}]},
                "settings": {"search": {"starts": 2, "sa_generations": 6, "lm_max_nfev": 3, "seed": 1}, "workers": 1}}
        r = client.post("/jobs/fit", json=body, headers=AUTH)
        assert r.status_code == 202, r.text
        job = svc.runner.wait(r.json()["id"], timeout=240)
        assert job["status"] == "succeeded", job["error"]
        result = client.get(f"/jobs/{job['id']}/result").json()
        assert result["fits"]["motor"]["parameters"]["R_w"] == pytest.approx(0.045)
        assert result["fits"]["motor"]["parameters"]["I_0"] == pytest.approx(2.1)
        assert result["parameter_set"]["motor"]["R_w"] == pytest.approx(0.045)
    finally:
        svc.close()


def test_fit_job_settings_name_the_model_variant_and_refuse_others():
    from gcs_pdm.service.fit_jobs import check_settings

    assert check_settings({"model": "paper"}) is None
    assert check_settings({"model": "extended"}) is None
    field, why = check_settings({"model": "spline"})
    assert field == "settings.model" and "paper" in why and "extended" in why


@pytest.mark.slow
def test_fit_job_without_a_model_setting_stores_an_extended_pack(tmp_path):
    """The extended variant is the default for new fits, through the service as on the command line."""
    from gcs_pdm.models.kernel import EXT_PACK_PARAMS

    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN))
    try:
        client = TestClient(create_app(svc))
        ids = _upload_llf20_flights(client)
        body = {"component": "battery", "packs": ["LLF20"], "save_as": "fitted_ext",
                "flights": {"train": [{"file_id": ids[0]}], "validation": [{"file_id": ids[1]}],
                            "test": [{"file_id": ids[2]}]},
                "settings": {"search": {"starts": 2, "sa_generations": 4, "lm_max_nfev": 3, "seed": 1}, "workers": 1}}
        r = client.post("/jobs/fit", json=body, headers=AUTH)
        assert r.status_code == 202, r.text
        job = svc.runner.wait(r.json()["id"], timeout=240)
        assert job["status"] == "succeeded", job["error"]
        stored = client.get("/parameter-sets/fitted_ext").json()["packs"]["LLF20"]
        assert stored["model"] == "extended" and set(stored["extended"]) == set(EXT_PACK_PARAMS)
    finally:
        svc.close()
