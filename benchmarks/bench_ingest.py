"""Ingesting a fleet's logs into pack records: 1,000 synthetic 20-minute tlogs, logs per minute on
1 and 2 local worker processes and on a Dask LocalCluster of 2 worker processes.

    python benchmarks/bench_ingest.py [--logs 1000] [--distinct 20] [--minutes 20] [--chemistry lipo] [--skip-dask]

The logs come from gcs_pdm/packs/synthetic.py: one pack per log with a serial, rated capacity and
cells (SMART_BATTERY_INFO), its BATTERY_STATUS at 2 Hz, the vehicle's HEARTBEAT at 1 Hz, and the bulk
a real tlog carries (ATTITUDE at 10 Hz, GLOBAL_POSITION_INT at 4 Hz: ≈ 0.9 MB per log). ``--distinct``
logs are written (10 packs, capacities and resistances apart) and copied up to ``--logs``, each copy
made unique by one extra ground-station heartbeat at its end, so every file has its own content hash
and is read, scanned and decoded in full (none is skipped as known). The Dask cluster's workers are
started as ``gcs_pdm.packs.ingest.local_cluster`` starts them (without the nanny's
MALLOC_TRIM_THRESHOLD_: see WORKER_ENVIRON there). Each engine ingests all logs
into a fresh SQLite database (the records written as they arrive, as `gcs-pdm packs ingest` does);
the figure is logs / wall minute of that run, start-up of the pool or cluster included. Floor: ≥ 200
logs/min with 2 workers. ``--chemistry`` is the packs' (the logs rest on its curve and are read on
it: ``liion`` reads capacity on the electrodes' curves, the slower method). The machine may be shared: figures are what this run measured. Last line:
one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import struct
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gcs_pdm.packs.ingest import IngestSettings, run_ingest  # noqa: E402
from gcs_pdm.packs.records import PackRecords  # noqa: E402
from gcs_pdm.packs.synthetic import SyntheticPack, write_pack_tlog  # noqa: E402

FLOOR_LOGS_PER_MIN = 200.0


def make_logs(out: Path, n: int, distinct: int, minutes: float, chemistry: str) -> list[Path]:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    bases = []
    for k in range(distinct):
        pack = SyntheticPack(serial=f"BENCH-{k % 10:02d}", capacity_ah=5.0 - 0.02 * k, resistance_ohm=0.02 + 0.001 * k,
                             chemistry=chemistry)
        p = out / f"base_{k:03d}.tlog"
        write_pack_tlog(p, pack, minutes=minutes, seed=k, epoch_s=1.7e9 + 3600 * k)
        bases.append(p.read_bytes())
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    paths = []
    for j in range(n):
        data = bases[j % distinct]
        stamp = struct.unpack(">Q", data[:8])[0] + int(minutes * 60e6) + j
        extra = struct.pack(">Q", stamp) + mavlink2.MAVLink_heartbeat_message(6, 8, 0, j % 256, 0, 3).pack(gcs)
        p = out / f"log_{j:05d}.tlog"
        p.write_bytes(data + extra)
        paths.append(p)
    return paths


def run(paths, workdir: Path, name: str, chemistry: str, **engine) -> dict:
    db_path = workdir / f"{name}.sqlite3"
    db = PackRecords(db_path)
    load_before = os.getloadavg()[0]  # the machine may be shared: what else ran is part of the figure
    t0 = time.perf_counter()
    summary = run_ingest(paths, IngestSettings(chemistry=chemistry), known=db.known_log, on_result=db.add_log_result, **engine)
    seconds = time.perf_counter() - t0
    records = sum(db.summary(p)["flights"] for p in db.pack_ids())
    db.close()
    return {"seconds": round(seconds, 2), "logs_per_min": round(len(paths) / seconds * 60.0, 1),
            "ingested": summary["ingested"], "bad": summary["bad"], "records": records, "engine": summary["engine"],
            "load_avg_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=1000)
    ap.add_argument("--distinct", type=int, default=20)
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--chemistry", default="lipo", help="the packs' chemistry (default lipo, as ingest's)")
    ap.add_argument("--skip-dask", action="store_true")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_ingest_"))
    try:
        t0 = time.perf_counter()
        paths = make_logs(work, args.logs, args.distinct, args.minutes, args.chemistry)
        made = time.perf_counter() - t0
        size_mb = sum(p.stat().st_size for p in paths) / 1e6
        print(f"{len(paths)} logs, {size_mb:.0f} MB, written in {made:.0f} s", flush=True)
        results = {}
        for name, engine in (("1 worker", {"workers": 1}), ("2 workers", {"workers": 2})):
            results[name] = run(paths, work, name.replace(" ", "_"), args.chemistry, **engine)
            print(f"{name}: {results[name]}", flush=True)
        if not args.skip_dask:
            from gcs_pdm.packs.ingest import local_cluster

            t0 = time.perf_counter()
            with local_cluster(2) as cluster:
                started = time.perf_counter() - t0
                r = run(paths, work, "dask", args.chemistry, scheduler=cluster.scheduler_address)
            r["cluster_start_s"] = round(started, 2)
            results["dask LocalCluster, 2 workers"] = r
            print(f"dask: {r}", flush=True)
        best2 = results["2 workers"]["logs_per_min"]
        out = {"bench": "ingest", "chemistry": args.chemistry, "logs": len(paths), "minutes_per_log": args.minutes,
               "mb_per_log": round(size_mb / len(paths), 2), "cpus": os.cpu_count(),
               "python": platform.python_version(), "floor_logs_per_min": FLOOR_LOGS_PER_MIN,
               "meets_floor": best2 >= FLOOR_LOGS_PER_MIN,
               "load_avg_at_end": [round(x, 2) for x in os.getloadavg()], **{k: v for k, v in results.items()}}
        print(json.dumps(out))
        return 0
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
