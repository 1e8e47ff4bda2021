"""HTTP edge cases that were 500s or unbounded (issue 12): ids past SQLite's int64, long names,
uploads bounded by size and rows and streamed to disk, a tlog that must be mostly MAVLink."""
from __future__ import annotations

import os
import struct

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.runtime import Service

TOKEN = "limits-test-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
BIG = str(2**63)  # one past SQLite's largest INTEGER


def make_service(tmp_path, **settings) -> Service:
    return Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN, **settings))


@pytest.fixture
def service(tmp_path):
    svc = make_service(tmp_path, max_upload_bytes=200_000, max_upload_rows=1000)
    yield svc
    svc.close()


@pytest.fixture
def client(service):
    return TestClient(create_app(service), raise_server_exceptions=False)


def heartbeats(n: int) -> bytes:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return b"".join(struct.pack(">Q", 1_700_000_000_000_000 + k * 100_000) + mav.heartbeat_encode(1, 3, 0, 0, 4).pack(mav)
                    for k in range(n))


def incoming_left(service) -> list[str]:
    folder = service.incoming_dir
    return sorted(os.listdir(folder)) if folder.exists() else []


@pytest.mark.parametrize("method,path", [
    ("get", f"/missions/plans/{BIG}"), ("post", f"/missions/plans/{BIG}/approve"),
    ("post", f"/missions/plans/{BIG}/reject"), ("post", f"/faults/{BIG}/clear"),
    ("post", f"/missions/uploads/{BIG}/revert"), ("get", f"/missions/plans/-{BIG}"),
    ("get", "/missions/plans/0"), ("get", f"/events/poll?since={BIG}"),
    ("get", "/jobs/" + "x" * 300), ("post", "/jobs/" + "x" * 300 + "/cancel"),
    ("get", "/parameter-sets/" + "p" * 300), ("post", "/parameter-sets/" + "p" * 300 + "/activate"),
    ("get", "/jobs/j/plots/" + "n" * 300),
])
def test_out_of_range_ids_and_long_names_are_422_not_500(client, method, path):
    r = getattr(client, method)(path, headers=AUTH)
    assert r.status_code == 422, (path, r.status_code, r.text)
    assert r.json()["detail"][0]["loc"][0] in ("path", "query")


def test_largest_row_id_is_a_plain_404(client):
    assert client.get(f"/missions/plans/{2**63 - 1}").status_code == 404
    assert client.post(f"/missions/plans/{2**63 - 1}/approve", headers=AUTH).status_code == 404


def test_odd_last_event_id_is_no_500(client, service):
    service.events.publish("policy", policy="auto")
    for header in ("²".encode("latin-1"), b"9" * 40):
        with client.stream("GET", "/events", headers={"Last-Event-ID": header}) as r:
            assert r.status_code == 200 and next(r.iter_lines()).startswith(":")


def test_long_or_odd_file_names(client, service):
    r = client.post("/files", files={"file": ("a" * 300 + ".tlog", heartbeats(3))}, headers=AUTH)
    assert r.status_code == 422 and "longer than 200 characters" in r.json()["detail"][0]["msg"]
    # 150 two-byte characters: 300 bytes, too long for a file system name unless stored safely
    for name in ("..tlog", " .tlog", "_.tlog"):  # no name before the suffix: refused (issue 34)
        r = client.post("/files", files={"file": (name, heartbeats(3))}, headers=AUTH)
        assert r.status_code == 422 and "no letter or digit" in r.text, (name, r.text)
    for name in ("é" * 150 + ".tlog", "a\x00b.tlog"):
        r = client.post("/files", files={"file": (name, heartbeats(3))}, headers=AUTH)
        assert r.status_code == 201, (name, r.text)
        stored = service.store.file(r.json()["id"])
        assert name.startswith("é") <= (stored["filename"] == name)  # the client's name is kept as given
        assert os.path.isfile(stored["path"]) and len(os.path.basename(stored["path"]).encode()) < 120
    assert incoming_left(service) == []


def test_upload_over_the_size_limit_is_413_and_leaves_nothing(client, service):
    data = heartbeats(5000)
    while len(data) <= 200_000:
        data += data
    r = client.post("/files", files={"file": ("big.tlog", data)}, headers=AUTH)
    assert r.status_code == 413 and "200000 bytes" in r.json()["detail"]
    assert client.get("/files").json() == [] and client.get("/tlogs").json() == []
    assert incoming_left(service) == [] and not list((service.config.data_path / "uploads").glob("*.tlog"))


def test_upload_is_received_in_chunks_not_read_whole(client, service, monkeypatch):
    from gcs_pdm.service import uploads
    from starlette.datastructures import UploadFile

    sizes = []
    read = UploadFile.read

    async def spy(self, size=-1):
        sizes.append(size)
        return await read(self, size)

    monkeypatch.setattr(UploadFile, "read", spy)
    monkeypatch.setattr(uploads, "CHUNK_BYTES", 4096)
    data = heartbeats(2000)
    r = client.post("/files", files={"file": ("f.tlog", data)}, headers=AUTH)
    assert r.status_code == 201 and r.json()["size_bytes"] == len(data)
    assert sizes and all(0 < s <= 4096 for s in sizes) and len(sizes) > len(data) // 4096


def test_random_bytes_with_a_few_valid_packets_are_no_tlog(client, service):
    rng = __import__("random").Random(7)
    junk = bytes(rng.getrandbits(8) for _ in range(150_000))
    data = bytearray(junk)
    for k, pkt in enumerate([heartbeats(1)] * 10):  # ten valid records scattered through the noise
        at = 10_000 * (k + 1)
        data[at:at + len(pkt)] = pkt
    r = client.post("/files", files={"file": ("noise.tlog", bytes(data))}, headers=AUTH)
    assert r.status_code == 422
    msg = r.json()["detail"][0]["msg"]
    assert "not a MAVLink tlog" in msg and "90%" in msg
    assert client.get("/tlogs").json() == [] and incoming_left(service) == []
    # mostly MAVLink with a little damage is still a tlog
    good = bytearray(heartbeats(4000))
    good[5000:5500] = b"\x00" * 500
    r = client.post("/files", files={"file": ("ok.tlog", bytes(good))}, headers=AUTH)
    assert r.status_code == 201, r.text


def test_mavlink_share_is_the_same_whatever_the_scan_window(tmp_path):
    from gcs_pdm.service.uploads import mavlink_fraction

    data = bytearray(heartbeats(3000))
    data[20_000:23_000] = os.urandom(3000)
    path = tmp_path / "x.tlog"
    path.write_bytes(data)
    whole = mavlink_fraction(path, window=1 << 30)
    assert 0.9 < whole < 0.98
    for window in (300, 1000, 4096, 65536):
        assert mavlink_fraction(path, window=window) == pytest.approx(whole, abs=1e-3)


def test_csv_over_the_row_limit_is_413(client, service):
    rows = b"".join(b"%d,10,20.1,25,20\n" % i for i in range(1001))
    r = client.post("/files", files={"file": ("many.csv", b"time_s,current_a,voltage_v,temperature_c,ambient_c\n" + rows)},
                    headers=AUTH)
    assert r.status_code == 413 and "1001 rows" in r.json()["detail"]
    ok = b"".join(b"%d,10,20.1,25,20\n" % i for i in range(1000))
    r = client.post("/files", files={"file": ("ok.csv", b"time_s,current_a,voltage_v,temperature_c,ambient_c\n" + ok)},
                    headers=AUTH)
    assert r.status_code == 201, r.text


def test_a_parquet_of_60m_rows_is_refused_from_its_footer_without_loading(tmp_path, monkeypatch):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = tmp_path / "many.parquet"
    block = pa.table({"time_s": pa.array(np.zeros(1_000_000, dtype=np.int8))})
    with pq.ParquetWriter(path, block.schema) as writer:
        for _ in range(60):
            writer.write_table(block)
    assert path.stat().st_size < 1_000_000  # a constant column compresses to almost nothing

    import gcs_pdm.fitting.logs as logs

    def no_loading(*_a, **_k):
        raise AssertionError("the table was loaded")

    monkeypatch.setattr(logs, "read_table", no_loading)
    svc = make_service(tmp_path / "data")  # the default limits
    try:
        client = TestClient(create_app(svc), raise_server_exceptions=False)
        r = client.post("/files", files={"file": ("many.parquet", path.read_bytes())}, headers=AUTH)
        assert r.status_code == 413 and "60000000 rows" in r.json()["detail"], r.text
        assert svc.config.max_upload_rows == 5_000_000 and svc.config.max_upload_bytes == 256 * 1024 * 1024
    finally:
        svc.close()


@pytest.mark.parametrize("ref,field", [
    ({"tlog_id": 2**63}, "tlog_id"), ({"tlog_id": -(2**63) - 1}, "tlog_id"), ({"file_id": "f" * 100}, "file_id"),
    ({"path": "a\x00b"}, "path"), ({"path": "a" * 5000}, "path"),
])
def test_fit_flight_refs_out_of_range_are_422(client, ref, field):
    body = {"flights": {"train": [ref], "validation": [{"tlog_id": 1}]}}
    r = client.post("/jobs/fit", json=body, headers=AUTH)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "flights", "train", 0, field]


def test_a_path_name_too_long_for_the_file_system_is_422(client):
    body = {"flights": {"train": [{"path": "fixtures/" + "a" * 400 + ".tlog"}], "validation": [{"tlog_id": 1}]}}
    r = client.post("/jobs/fit", json=body, headers=AUTH)
    assert r.status_code == 422 and "cannot be read" in r.json()["detail"][0]["msg"], r.text


@pytest.mark.parametrize("path,body", [
    ("/faults", {"motor": "aft", "magnitude": 0.5, "note": "n" * 2001}),
    ("/missions/plans/1/approve", {"note": "n" * 2001}),
    ("/jobs/fit", {"save_as": "s" * 81, "flights": {"train": [{"tlog_id": 1}], "validation": [{"tlog_id": 1}]}}),
])
def test_unbounded_text_fields_are_bounded(client, path, body):
    r = client.post(path, json=body, headers=AUTH)
    assert r.status_code == 422 and r.json()["detail"][0]["type"] == "string_too_long", r.text


def test_an_oversized_body_is_refused_before_it_is_received(client, service):
    from gcs_pdm.service.uploads import MULTIPART_OVERHEAD_BYTES

    limit = service.config.max_upload_bytes + MULTIPART_OVERHEAD_BYTES
    # declared too large: refused from the header, nothing read
    r = client.post("/files", content=b"x" * 10, headers={**AUTH, "Content-Length": str(limit + 1),
                                                         "Content-Type": "multipart/form-data; boundary=b"})
    assert r.status_code == 413 and "upload limit" in r.json()["detail"]
    # sent in pieces without a length: refused once the limit is passed, the rest never pulled
    import asyncio

    pulled, sent = [], []
    first = b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.tlog"\r\n\r\n'

    async def receive():
        k = len(pulled)
        pulled.append(k)
        return {"type": "http.request", "body": first if k == 0 else b"\0" * 16_384, "more_body": k < 99}

    async def send(message):
        sent.append(message)

    scope = {"type": "http", "method": "POST", "path": "/files", "raw_path": b"/files", "query_string": b"",
             "root_path": "", "scheme": "http", "server": ("test", 80), "client": ("test", 1), "http_version": "1.1",
             "headers": [(b"authorization", AUTH["Authorization"].encode()),
                         (b"content-type", b"multipart/form-data; boundary=b")]}
    asyncio.run(create_app(service)(scope, receive, send))
    assert sent[0]["status"] == 413
    assert len(pulled) < 100 and (len(pulled) - 1) * 16_384 <= limit + 16_384, len(pulled)
    assert incoming_left(service) == []
