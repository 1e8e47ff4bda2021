"""The small defects of issue 34: non-finite JSON numbers were a 500, a read-only data directory a
22-line traceback, ``..csv`` was accepted, /tlogs showed server paths, a CSV with ``\\r`` line
endings got round the row cap, and JSON bodies had no size limit."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.runtime import Service

TOKEN = "small-faults-token-4Kp9wQ"
AUTH = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def service(tmp_path):
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, max_upload_rows=1000))
    yield svc
    svc.close()


@pytest.fixture
def client(service):
    return TestClient(create_app(service), raise_server_exceptions=False)


@pytest.mark.parametrize("number", ["NaN", "Infinity", "-Infinity", "1e309", "-2e400"])
@pytest.mark.parametrize("path,body", [
    ("/faults", '{"motor": "fwd", "magnitude": %s, "replan": false}'),
    ("/jobs/fit", '{"component": "battery", "flights": {"train": [{"file_id": "x"}]}, '
                  '"settings": {"search": {"lm_ftol": %s}}}'),
    ("/missions/plans/1/approve", '{"note": "ok", "weight": %s}'),
])
def test_non_finite_numbers_in_json_bodies_are_422(client, path, body, number):
    r = client.post(path, content=body % number, headers=AUTH)
    assert r.status_code == 422, (r.status_code, r.text)
    assert r.json()["detail"][0]["loc"] == ["body"]


def test_a_json_body_over_the_limit_is_413_with_or_without_a_token(client):
    body = '{"motor": "fwd", "magnitude": 0.1, "note": "%s"}' % ("x" * 1_100_000)  # max_json_bytes: 1 MiB
    for headers in (AUTH, {"Content-Type": "application/json"}):
        r = client.post("/faults", content=body, headers=headers)
        assert r.status_code == 413 and "max_json_bytes" in r.json()["detail"], r.text


def test_a_body_within_the_limit_still_works(client):
    r = client.post("/faults", json={"motor": "fwd", "magnitude": 0.25, "replan": False}, headers=AUTH)
    assert r.status_code == 201, r.text


@pytest.mark.parametrize("name", ["..csv", ".csv", "_.parquet", " .tlog", "-.csv"])
def test_names_with_nothing_before_the_suffix_are_refused(client, name):
    good = b"time_s,current_a,voltage_v,temperature_c,ambient_c\n0,10,20.1,25,20\n1,10,20.0,25.1,20\n"
    assert client.post("/files", files={"file": ("flight.csv", good)},
                       headers={"Authorization": f"Bearer {TOKEN}"}).status_code == 201
    r = client.post("/files", files={"file": (name, good)}, headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 422, (name, r.status_code, r.text)


@pytest.mark.parametrize("ending", [b"\r", b"\n", b"\r\n"])
def test_csv_rows_are_counted_at_any_line_ending(client, ending):
    rows = ending.join(b"%d,10,20.0,25,20" % k for k in range(1500))
    body = b"time_s,current_a,voltage_v,temperature_c,ambient_c" + ending + rows + ending
    r = client.post("/files", files={"file": ("flight.csv", body)}, headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 413 and "1500 rows" in r.json()["detail"], r.text


def test_line_counting_across_chunks():
    from gcs_pdm.service.uploads import LineCounter

    c = LineCounter()
    for chunk in (b"a,b,c\r", b"\n1,2,3\r", b"4,5,6\r", b"\n7,8,9\n"):
        c.feed(chunk)
    assert c.endings == 4 and c.header_fields() == 3


def test_tlogs_are_shown_relative_to_the_data_directory(service, client, tmp_path):
    (tmp_path / "tlogs").mkdir(exist_ok=True)
    inside = tmp_path / "tlogs" / "live_1.tlog"
    inside.write_bytes(b"")
    outside = tmp_path.parent / f"elsewhere_{tmp_path.name}.tlog"
    outside.write_bytes(b"")
    service.store.add_tlog(str(inside))
    service.store.add_tlog(str(outside))
    try:
        assert [t["path"] for t in client.get("/tlogs").json()] == ["tlogs/live_1.tlog", outside.name]
    finally:
        outside.unlink()


def test_a_read_only_data_directory_is_one_line_and_exit_2(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root to mount a read-only tmpfs (root ignores directory permissions)")
    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(ro)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        (ro / "data").mkdir()
        subprocess.run(["mount", "-o", "remount,ro", str(ro)], check=True)
        env = {k: v for k, v in os.environ.items() if not k.startswith("GCS_PDM_")}
        env["PYTHONPATH"] = str(REPO)
        out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "serve", "--data-dir", str(ro / "data"),
                              "--http", "127.0.0.1:0", "--mavlink", "udpin:127.0.0.1:0"],
                             capture_output=True, text=True, env=env, timeout=120)
    finally:
        subprocess.run(["umount", "-l", str(ro)], check=False)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gcs-pdm serve: error: database ") and "writable" in lines[0], out.stderr
