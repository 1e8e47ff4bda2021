"""Many logs into pack records: each log read, split into flights, and a health point made per
flight per pack; on a local process pool (default) or a Dask cluster (``dask.distributed``).

``ingest_one`` is the unit of work (a path and its content hash in, a plain dict out, never an
exception: a bad log comes back with ``status="bad"`` and why). The caller (:func:`run_ingest`)
hashes each file first and skips those already ingested (resumable), hands the rest to the
workers, and gets each result back in the order they finish (``on_result`` stores it: one writer).
"""
from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from gcs_pdm.packs.flights import split_flights
from gcs_pdm.packs.cell_curves import pack_health_point
from gcs_pdm.packs.health import HealthSettings
from gcs_pdm.packs.identity import identify
from gcs_pdm.packs.logs import LOG_KINDS, PackLogError, read_pack_log

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class IngestSettings:
    #: a silence this long ends a flight (as live: ServiceConfig.flight_end_after_link_lost_s)
    link_lost_end_s: float = 300.0
    #: the rated capacity of a pack whose log does not say it (None: such a pack is skipped, counted)
    default_capacity_ah: float | None = None
    #: the operator's slot -> pack assignments
    assignments: tuple[tuple[str, str], ...] = ()
    #: the packs' chemistry (a log does not say it): what their capacity is read on (packs/cell_curves.py);
    #: the vehicle description's default
    chemistry: str = "lipo"
    health: HealthSettings = field(default_factory=HealthSettings)


def content_hash(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def find_logs(args: Iterable[str | Path]) -> list[Path]:
    """Log files named, and those under named directories (by extension), sorted and unique."""
    out = []
    for a in args:
        p = Path(a)
        if p.is_dir():
            out += [q for q in p.rglob("*") if q.is_file() and q.suffix.lower() in LOG_KINDS]
        else:
            out.append(p)
    return sorted(set(out))


def _flight_windows(pack_log, link_lost_end_s: float) -> list[tuple[float, float, float, float, str, str]]:
    """(window start, flight start, flight end, window end, begin reason, end reason) per flight: the
    window takes in the rests around the flight, up to halfway to the neighbouring flights."""
    if pack_log.armed is None:
        t = np.concatenate([s.time_s for s in pack_log.slots])
        lo, hi = float(np.nanmin(t)), float(np.nanmax(t))
        return [(lo, lo, hi, hi, "log start", "log end")]
    ta, arm = pack_log.armed
    spans = split_flights(ta, arm, link_lost_end_s)
    if not spans:
        return []
    t_all = np.concatenate([s.time_s for s in pack_log.slots])
    lo, hi = float(np.nanmin(t_all)), float(np.nanmax(t_all))
    flights = [(float(ta[a]), float(ta[b - 1]), why_b, why_e) for a, b, why_b, why_e in spans]
    out = []
    for k, (start, end, why_b, why_e) in enumerate(flights):
        w0 = lo if k == 0 else 0.5 * (flights[k - 1][1] + start)
        w1 = hi if k == len(flights) - 1 else 0.5 * (end + flights[k + 1][0])
        out.append((w0, start, end, w1, why_b, why_e))
    return out


def records_from_log(path: str | Path, log_hash: str, settings: IngestSettings = IngestSettings()) -> tuple[list[dict], list[str]]:
    """The pack records (one per flight per pack) of one log, and its warnings. Raises PackLogError."""
    pack_log = read_pack_log(path)
    warnings = list(pack_log.notes)
    assignments = dict(settings.assignments)
    records = []
    windows = _flight_windows(pack_log, settings.link_lost_end_s)
    if not windows:
        warnings.append("the vehicle was never armed in this log: no flight")
    for k, (w0, start, end, w1, why_b, why_e) in enumerate(windows):
        for s in pack_log.slots:
            m = (s.time_s >= w0) & (s.time_s <= w1)
            if m.sum() < 2:
                continue
            ident = identify(s.slot, s.serial, assignments)
            if ident.warning:
                warnings.append(ident.warning)
            nominal = s.rated_capacity_ah or settings.default_capacity_ah
            if not nominal:
                warnings.append(f"{s.slot}: rated capacity unknown (not in the log; give --capacity-ah): skipped")
                continue
            cells = s.cells_series
            if not cells:
                v = s.voltage_v[m]
                vmax = float(np.nanmax(v)) if np.isfinite(v).any() else 0.0
                cells = max(1, int(round(vmax / 4.1)))
            hp = pack_health_point(ident.pack_id, s.time_s[m], s.current_a[m], s.voltage_v[m], s.temperature_c[m],
                                   chemistry=settings.chemistry, nominal_capacity_ah=nominal, cells_series=cells,
                                   settings=settings.health)
            records.append({"log_hash": log_hash, "log_path": str(path), "flight_index": k, "slot": s.slot,
                            "pack_id": ident.pack_id, "identity": ident.source,
                            "order_s": (pack_log.epoch_s + start) if pack_log.epoch_s is not None else None,
                            "flight": {"start_s": start, "end_s": end, "begin_reason": why_b, "end_reason": why_e},
                            "health": hp.to_dict()})
    return records, sorted(set(warnings))


def ingest_one(path: str, log_hash: str, settings: IngestSettings = IngestSettings()) -> dict:
    """One log's result as a plain dict (picklable, for any worker): never raises."""
    try:
        records, warnings = records_from_log(path, log_hash, settings)
        return {"hash": log_hash, "path": str(path), "status": "ok", "error": None, "records": records,
                "warnings": warnings}
    except (PackLogError, ValueError, OSError) as exc:
        return {"hash": log_hash, "path": str(path), "status": "bad", "error": str(exc), "records": [], "warnings": []}
    except Exception as exc:  # noqa: BLE001 - one bad log never stops the batch; said, with its type
        return {"hash": log_hash, "path": str(path), "status": "bad", "error": f"{type(exc).__name__}: {exc}",
                "records": [], "warnings": []}


def _worker_init() -> None:
    from gcs_pdm import process_threads

    process_threads.one_blas_thread()


def run_ingest(paths: Iterable[str | Path], settings: IngestSettings = IngestSettings(), *, workers: int | None = None,
               scheduler: str | None = None, known: Callable[[str], bool] = lambda h: False,
               on_result: Callable[[dict], None] = lambda r: None, progress: bool = False) -> dict:
    """Ingest ``paths``: those whose content hash ``known`` says was ingested are skipped; each other
    result goes to ``on_result`` as it finishes. ``scheduler``: a Dask scheduler address
    (``tcp://HOST:8786``) or a ``distributed.Client``/``LocalCluster``; else a local process pool of
    ``workers`` processes (default: the CPUs; 1: in this process). A summary dict."""
    paths = [Path(p) for p in paths]
    todo, skipped, unreadable = [], 0, []
    for p in paths:
        try:
            h = content_hash(p)
        except OSError as exc:
            unreadable.append({"hash": None, "path": str(p), "status": "bad", "error": f"cannot be read: {exc}",
                               "records": [], "warnings": []})
            continue
        if known(h):
            skipped += 1
        else:
            todo.append((str(p), h))
    counts = {"ok": 0, "bad": 0, "records": 0}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo) + len(unreadable), unit="log", desc="ingest")

    def take(result: dict) -> None:
        counts[result["status"]] += 1
        counts["records"] += len(result["records"])
        if result["status"] == "bad":
            log.warning("%s: skipped: %s", result["path"], result["error"])
        on_result(result)
        if bar is not None:
            bar.update(1)

    for r in unreadable:
        take(r)
    engine = "in process"
    if scheduler is not None:
        engine = _run_dask(todo, settings, scheduler, take)
    elif (workers or os.cpu_count() or 1) <= 1 or len(todo) <= 1:
        _worker_init()
        for p, h in todo:
            take(ingest_one(p, h, settings))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        n = workers or os.cpu_count() or 1
        engine = f"local process pool of {n}"
        with ProcessPoolExecutor(max_workers=n, initializer=_worker_init) as pool:
            futures = [pool.submit(ingest_one, p, h, settings) for p, h in todo]
            for fut in as_completed(futures):
                take(fut.result())
    if bar is not None:
        bar.close()
    return {"logs": len(paths), "skipped_known": skipped, "ingested": counts["ok"], "bad": counts["bad"],
            "records": counts["records"], "engine": engine}


#: what the Dask nanny puts in its workers' environment for this work. Its default adds
#: MALLOC_TRIM_THRESHOLD_=65536 (to hand memory back to the OS), with which every log's buffers are
#: mapped and unmapped afresh: 3x the CPU per log, 3x the wall time of a 2-worker run (measured,
#: docs/packs.md). Workers of a cluster started elsewhere: set the same in their Dask config.
WORKER_ENVIRON = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}


def local_cluster(n_workers: int = 2):
    """A ``distributed.LocalCluster`` of ``n_workers`` single-threaded worker processes started with
    :data:`WORKER_ENVIRON` (tests, the benchmark; ``--scheduler`` takes any cluster's address)."""
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.nanny.pre-spawn-environ": dict(WORKER_ENVIRON)}):
        return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None)


def _run_dask(todo, settings, scheduler, take) -> str:
    from distributed import Client, as_completed

    own = isinstance(scheduler, str)
    client = Client(scheduler) if own else (scheduler if isinstance(scheduler, Client) else Client(scheduler))
    try:
        futures = client.map(ingest_one, [p for p, _ in todo], [h for _, h in todo], settings=settings, pure=False)
        for fut in as_completed(futures):
            take(fut.result())
            fut.release()
        return f"dask scheduler {client.scheduler.address}"
    finally:
        if own or not isinstance(scheduler, Client):
            client.close()
