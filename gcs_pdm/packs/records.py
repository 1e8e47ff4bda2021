"""The packs' records in SQLite (shell): a health point per flight per pack, the logs ingested
(by content hash: what makes ingest resumable), and the operator's slot assignments.

Its own tables in the service's database file (``gcs-pdm packs`` and the service open the same
file; WAL lets them share it). ``CREATE TABLE IF NOT EXISTS``: an existing database gains them and
keeps everything else.
"""
from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path

from gcs_pdm.packs.health import HealthPoint
from gcs_pdm.packs.trend import estimator_priors, pack_trend

_SCHEMA = [
    """CREATE TABLE IF NOT EXISTS pack_health (
        id INTEGER PRIMARY KEY AUTOINCREMENT, pack_id TEXT NOT NULL, slot TEXT NOT NULL, identity TEXT NOT NULL,
        log_hash TEXT, flight_index INTEGER, flight_id INTEGER, order_s REAL, body TEXT NOT NULL,
        created_at REAL NOT NULL, UNIQUE(log_hash, flight_index, slot))""",
    "CREATE INDEX IF NOT EXISTS pack_health_pack ON pack_health(pack_id)",
    """CREATE TABLE IF NOT EXISTS ingested_logs (
        hash TEXT PRIMARY KEY, path TEXT NOT NULL, status TEXT NOT NULL, error TEXT, records INTEGER NOT NULL,
        warnings TEXT NOT NULL, created_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS pack_assignments (
        slot TEXT PRIMARY KEY, pack_id TEXT NOT NULL, note TEXT, assigned_at REAL NOT NULL)""",
]


class PackRecords:
    def __init__(self, path: str | Path, clock=time.time):
        if str(path) != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        self._clock = clock
        self._lock = threading.RLock()
        self._db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None, timeout=30.0)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        with self._lock:
            for stmt in _SCHEMA:
                self._db.execute(stmt)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # --- ingest ------------------------------------------------------------------------------

    def known_log(self, log_hash: str) -> bool:
        """Ingested already (ok; a bad log is tried again next time, the code may have learned it)."""
        row = self._db.execute("SELECT status FROM ingested_logs WHERE hash=?", (log_hash,)).fetchone()
        return row is not None and row["status"] == "ok"

    def add_log_result(self, result: dict) -> None:
        """One log's :func:`gcs_pdm.packs.ingest.ingest_one` result, records and all, in one transaction."""
        if result.get("hash") is None:
            return  # unreadable: nothing to key it by, reported by the caller
        now = self._clock()
        with self._lock:
            self._db.execute("BEGIN")
            try:
                for r in result["records"]:
                    self._db.execute(
                        "INSERT OR REPLACE INTO pack_health(pack_id, slot, identity, log_hash, flight_index, flight_id, "
                        "order_s, body, created_at) VALUES(?,?,?,?,?,?,?,?,?)",
                        (r["pack_id"], r["slot"], r["identity"], r["log_hash"], r["flight_index"], None,
                         r.get("order_s"), json.dumps(r), now))
                self._db.execute("INSERT OR REPLACE INTO ingested_logs(hash, path, status, error, records, warnings, "
                                 "created_at) VALUES(?,?,?,?,?,?,?)",
                                 (result["hash"], result["path"], result["status"], result["error"],
                                  len(result["records"]), json.dumps(result.get("warnings", [])), now))
                self._db.execute("COMMIT")
            except Exception:
                self._db.execute("ROLLBACK")
                raise

    def add_live_point(self, flight_id: int, slot: str, identity: str, point: HealthPoint, flight: dict) -> None:
        """A health point the service made at a flight's end."""
        rec = {"log_hash": None, "log_path": None, "flight_index": None, "flight_id": flight_id, "slot": slot,
               "pack_id": point.pack_id, "identity": identity, "order_s": None, "flight": flight,
               "health": point.to_dict()}
        with self._lock:
            self._db.execute(
                "INSERT INTO pack_health(pack_id, slot, identity, log_hash, flight_index, flight_id, order_s, body, "
                "created_at) VALUES(?,?,?,?,?,?,?,?,?)",
                (point.pack_id, slot, identity, f"live:{flight_id}", 0, flight_id, self._clock(), json.dumps(rec),
                 self._clock()))

    def logs(self, limit: int = 1000) -> list[dict]:
        rows = self._db.execute("SELECT * FROM ingested_logs ORDER BY created_at DESC LIMIT ?", (limit,)).fetchall()
        return [{**dict(r), "warnings": json.loads(r["warnings"])} for r in rows]

    # --- assignments -------------------------------------------------------------------------

    def assign(self, slot: str, pack_id: str, note: str = "") -> dict:
        with self._lock:
            self._db.execute("INSERT OR REPLACE INTO pack_assignments(slot, pack_id, note, assigned_at) VALUES(?,?,?,?)",
                             (slot, pack_id, note, self._clock()))
        return self.assignments()[slot]

    def unassign(self, slot: str) -> bool:
        with self._lock:
            return self._db.execute("DELETE FROM pack_assignments WHERE slot=?", (slot,)).rowcount > 0

    def assignments(self) -> dict[str, dict]:
        return {r["slot"]: dict(r) for r in self._db.execute("SELECT * FROM pack_assignments ORDER BY slot")}

    # --- packs -------------------------------------------------------------------------------

    def records(self, pack_id: str) -> list[dict]:
        """The pack's records in flight order (absolute time where known, then log and flight)."""
        rows = self._db.execute("SELECT body, order_s, created_at FROM pack_health WHERE pack_id=?", (pack_id,)).fetchall()
        recs = [json.loads(r["body"]) for r in rows]
        recs.sort(key=lambda r: (r.get("order_s") is None, r.get("order_s") or 0.0, r.get("log_path") or "",
                                 r.get("flight_index") or 0))
        return recs

    def points(self, pack_id: str) -> list[HealthPoint]:
        return [HealthPoint.from_dict(r["health"]) for r in self.records(pack_id)]

    def pack_ids(self) -> list[str]:
        return [r["pack_id"] for r in self._db.execute("SELECT DISTINCT pack_id FROM pack_health ORDER BY pack_id")]

    def summary(self, pack_id: str, *, capacity_fraction: float = 0.8, resistance_factor: float = 1.5) -> dict:
        """A pack's identity, latest health, trend and retirement forecast."""
        recs = self.records(pack_id)
        if not recs:
            raise KeyError(f"pack {pack_id!r}")
        points = [HealthPoint.from_dict(r["health"]) for r in recs]
        trend = pack_trend(pack_id, points, capacity_fraction=capacity_fraction, resistance_factor=resistance_factor)
        cycles = 0.0
        history = []
        for r, p in zip(recs, points):
            history.append({"cycles": cycles, "capacity_ah": p.capacity_ah, "capacity_sd_ah": p.capacity_sd_ah,
                            "resistance_25c_ohm": p.resistance_25c_ohm, "resistance_sd_ohm": p.resistance_sd_ohm,
                            "charge_ah": p.charge_ah, "energy_wh": p.energy_wh,
                            "equivalent_cycles": p.equivalent_cycles, "depth_of_discharge": p.depth_of_discharge,
                            "peak_temperature_c": p.peak_temperature_c, "slot": r["slot"], "identity": r["identity"],
                            "log_path": r.get("log_path"), "flight_index": r.get("flight_index"),
                            "flight_id": r.get("flight_id"), "why": p.why})
            cycles += p.equivalent_cycles
        identities = sorted({r["identity"] for r in recs})
        return {"pack_id": pack_id, "flights": len(recs), "identity": identities,
                "slots": sorted({r["slot"] for r in recs}),
                "warning": next((f"known only by slot name {r['slot']!r}: packs rotated between slots or aircraft "
                                 "are mixed up" for r in recs if r["identity"] == "slot name"), None),
                "equivalent_cycles": cycles, "latest": history[-1], "priors": estimator_priors(points),
                "thresholds": {"capacity_fraction": capacity_fraction, "resistance_factor": resistance_factor},
                "trend": trend.to_dict(), "history": history}
