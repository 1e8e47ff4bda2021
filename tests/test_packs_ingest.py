"""Ingesting logs into pack records: synthetic tlogs of packs with a known capacity and resistance
(gcs_pdm/packs/synthetic.py), a bad log among them, resumable by content hash; a real Dask
LocalCluster gives the same records as the local process pool; the CLI's list and show."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from gcs_pdm.packs.ingest import IngestSettings, content_hash, run_ingest
from gcs_pdm.packs.records import PackRecords
from gcs_pdm.packs.synthetic import SyntheticPack, write_pack_tlog

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared"


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Two packs, three flights each, one with no serial (slot name), and a bad log."""
    d = tmp_path_factory.mktemp("logs")
    truth = {}
    for k in range(3):
        for serial, cap, r in (("PK-A", 4.8 - 0.1 * k, 0.020 + 0.002 * k), ("PK-B", 4.0, 0.030)):
            p = d / f"{serial}_{k}.tlog"
            truth[p.name] = write_pack_tlog(p, SyntheticPack(serial=serial, capacity_ah=cap, resistance_ohm=r),
                                            epoch_s=1.7e9 + 86400 * k, seed=k, bulk=False)
    write_pack_tlog(d / "noserial.tlog", SyntheticPack(serial=""), seed=9, bulk=False)
    (d / "broken.tlog").write_bytes(b"\x00garbage" * 1000)
    (d / "notes.txt").write_text("not a log")
    return d, truth


def ingest(paths, **kw):
    results = []
    summary = run_ingest(paths, IngestSettings(), on_result=results.append, **kw)
    return summary, sorted((r for r in results), key=lambda r: r["path"])


def comparable(results):
    out = []
    for r in results:
        recs = [{**x, "log_path": Path(x["log_path"]).name} for x in r["records"]]
        out.append((Path(r["path"]).name, r["status"], r["error"], json.dumps(recs, sort_keys=True)))
    return out


def test_health_points_recover_each_pack(logs):
    d, truth = logs
    summary, results = ingest(sorted(d.glob("*.tlog")), workers=2)
    assert summary["logs"] == 8 and summary["ingested"] == 7 and summary["bad"] == 1
    bad, = [r for r in results if r["status"] == "bad"]
    assert bad["path"].endswith("broken.tlog") and "heartbeat" in bad["error"]
    for r in results:
        if r["path"].endswith(("broken.tlog", "noserial.tlog")):
            continue
        rec, = r["records"]
        t = truth[Path(r["path"]).name]
        h = rec["health"]
        assert rec["pack_id"] == t["serial"] and rec["identity"] == "autopilot serial"
        assert rec["flight"]["begin_reason"] == "armed" and rec["flight"]["end_reason"] == "disarmed"
        # the synthetic pack sits on the generic curve, so its capacity is read to the noise
        assert abs(h["capacity_ah"] / t["capacity_ah"] - 1.0) < 0.03
        assert abs(h["capacity_ah"] - t["capacity_ah"]) < 3 * h["capacity_sd_ah"]
        assert abs(h["resistance_25c_ohm"] / t["resistance_ohm"] - 1.0) < 0.1
        assert abs(h["charge_ah"] - t["drawn_ah"]) < 0.01
        assert h["equivalent_cycles"] == pytest.approx(h["charge_ah"] / 5.0)
    noserial, = [r for r in results if r["path"].endswith("noserial.tlog")]
    assert noserial["records"][0]["pack_id"] == "battery0"
    assert any("slot" in w for w in noserial["warnings"])


def test_ingest_is_resumable_by_content_hash(logs, tmp_path):
    d, _ = logs
    db = PackRecords(tmp_path / "p.sqlite3")
    try:
        paths = sorted(d.glob("*.tlog"))
        first = run_ingest(paths, workers=1, known=db.known_log, on_result=db.add_log_result)
        assert first["ingested"] == 7 and first["bad"] == 1
        copy = tmp_path / "renamed.tlog"
        shutil.copy(paths[0], copy)  # the same content under another name: known
        again = run_ingest(paths + [copy], workers=1, known=db.known_log, on_result=db.add_log_result)
        assert again["skipped_known"] == 8 and again["ingested"] == 0 and again["bad"] == 1  # a bad log is retried
        assert db.known_log(content_hash(copy))
        assert sorted(db.pack_ids()) == ["PK-A", "PK-B", "battery0"]
        a = db.summary("PK-A")
        assert a["flights"] == 3 and [round(h["capacity_ah"], 1) for h in a["history"]] == [4.8, 4.7, 4.6]
        assert a["priors"]["capacity_ah"] == pytest.approx(a["history"][-1]["capacity_ah"])
        assert db.summary("battery0")["warning"]
    finally:
        db.close()


def test_a_dask_local_cluster_gives_the_same_records_as_the_local_pool(logs):
    distributed = pytest.importorskip("distributed")
    d, _ = logs
    paths = sorted(d.glob("*.tlog"))
    _, pool = ingest(paths, workers=2)
    from gcs_pdm.packs.ingest import local_cluster

    with local_cluster(2) as cluster:
        assert isinstance(cluster, distributed.LocalCluster)
        summary, on_dask = ingest(paths, scheduler=cluster.scheduler_address)
    assert summary["engine"].startswith("dask scheduler tcp://")
    assert comparable(on_dask) == comparable(pool)
    assert sum(len(r["records"]) for r in on_dask) == 7


def test_the_cli_ingests_lists_and_shows(logs, tmp_path, capsys):
    from gcs_pdm.cli import main

    d, _ = logs
    db = tmp_path / "cli.sqlite3"
    assert main(["packs", "--database", str(db), "ingest", str(d), "--workers", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ingested"] == 7 and out["bad"] == 1 and out["bad_logs"][0]["path"].endswith("broken.tlog")
    assert main(["packs", "--database", str(db), "list", "--json"]) == 0
    listed = {p["pack_id"]: p for p in json.loads(capsys.readouterr().out)}
    assert listed["PK-A"]["flights"] == 3 and listed["PK-B"]["flights"] == 3
    assert main(["packs", "--database", str(db), "show", "PK-A"]) == 0
    text = capsys.readouterr().out
    assert "pack PK-A: 3 flight(s)" in text and "retirement:" in text
    assert main(["packs", "--database", str(db), "show", "nope"]) == 2  # an input error (docs/cli.md)


@pytest.mark.skipif(not (SHARED / "logs").is_dir(), reason="no shared logs")
def test_real_autopilot_logs_ingest_or_are_reported(tmp_path):
    paths = sorted(p for p in (SHARED / "logs").iterdir() if p.suffix.lower() in (".tlog", ".bin", ".ulg"))
    summary, results = ingest(paths, workers=1)
    assert summary["logs"] == len(paths) and summary["ingested"] + summary["bad"] == len(paths)
    for r in results:
        assert r["status"] == "ok" or r["error"]
