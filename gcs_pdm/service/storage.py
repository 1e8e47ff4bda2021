"""SQLite persistence: parameter sets with provenance, jobs and results, faults, plans, uploads,
uploaded flight files and the tlog index.

One file, WAL journal (readers never wait for the writer), a versioned schema applied at open.
Every row keeps its payload as JSON beside a few indexed columns, so the HTTP layer can return
it unchanged and new fields need no migration. A job found ``running``/``queued`` when the store
opens belonged to a process that died: it becomes ``interrupted`` (kept, never lost).
"""
from __future__ import annotations

import json
import logging
import math
import sqlite3
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Iterable

from gcs_pdm.diagnosis.faults import Fault
from gcs_pdm.models.params import BUILTIN_SETS, ParameterSet

log = logging.getLogger(__name__)

SCHEMA_VERSION = 2

_SCHEMA = [
    """CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS parameter_sets (
        name TEXT PRIMARY KEY, body TEXT NOT NULL, provenance TEXT NOT NULL, builtin INTEGER NOT NULL,
        active INTEGER NOT NULL DEFAULT 0, created_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS jobs (
        id TEXT PRIMARY KEY, kind TEXT NOT NULL, status TEXT NOT NULL, progress REAL NOT NULL,
        stage TEXT NOT NULL, request TEXT NOT NULL, result TEXT, error TEXT,
        created_at REAL NOT NULL, updated_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS faults (
        id INTEGER PRIMARY KEY AUTOINCREMENT, time_s REAL, kind TEXT NOT NULL, target TEXT,
        magnitude REAL, source TEXT NOT NULL, active INTEGER NOT NULL, body TEXT NOT NULL, created_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS plans (
        id INTEGER PRIMARY KEY AUTOINCREMENT, time_s REAL, trigger TEXT NOT NULL, status TEXT NOT NULL,
        body TEXT NOT NULL, created_at REAL NOT NULL, updated_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS uploads (
        id INTEGER PRIMARY KEY AUTOINCREMENT, plan_id INTEGER, status TEXT NOT NULL, body TEXT NOT NULL,
        created_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS files (
        id TEXT PRIMARY KEY, filename TEXT NOT NULL, path TEXT NOT NULL, kind TEXT NOT NULL,
        size_bytes INTEGER NOT NULL, created_at REAL NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS tlogs (
        id INTEGER PRIMARY KEY AUTOINCREMENT, path TEXT UNIQUE NOT NULL, started_at REAL NOT NULL,
        ended_at REAL, size_bytes INTEGER, note TEXT)""",
    # schema 2: flights as records (gcs_pdm.packs.flights says where one begins and ends)
    """CREATE TABLE IF NOT EXISTS flights (
        id INTEGER PRIMARY KEY AUTOINCREMENT, started_s REAL NOT NULL, last_s REAL NOT NULL, ended_s REAL,
        begin_reason TEXT NOT NULL, end_reason TEXT, body TEXT NOT NULL, created_at REAL NOT NULL, ended_at REAL)""",
]

#: schema 2: what belongs to a flight carries its id (NULL: before flights were recorded, or on the ground)
_FLIGHT_COLUMNS = ("faults", "plans", "uploads")

JOB_FINAL = frozenset({"succeeded", "failed", "cancelled", "interrupted"})


class NotFound(KeyError):
    """No row with that id/name."""


class Conflict(ValueError):
    """The request contradicts what is stored (e.g. overwriting a built-in set)."""


def _dumps(obj: Any) -> str:
    return json.dumps(obj, allow_nan=False, default=_json_default)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "to_dict"):
        return obj.to_dict()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


class Store:
    """Thread-safe access to the service database (one connection, one lock)."""

    def __init__(self, path: str | Path, clock=time.time):
        self.path = Path(path)
        if str(path) != ":memory:":
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._clock = clock
        self._lock = threading.RLock()
        self._db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute("PRAGMA foreign_keys=ON")
        #: the open flight's id (set by service/flights.py); faults, plans and uploads stored now carry it
        self.current_flight_id: int | None = None
        #: when this store was opened: a fault stored before it with no flight is a previous run's
        self.opened_at = clock()
        self._migrate()
        self.interrupted_at_open = self._interrupt_orphans()
        self._seed_builtins()

    # --- housekeeping --------------------------------------------------------------------------

    def _migrate(self) -> None:
        with self._lock:
            for stmt in _SCHEMA:
                self._db.execute(stmt)
            for table in _FLIGHT_COLUMNS:  # an older database gains the column; its rows keep NULL
                if "flight_id" not in {r["name"] for r in self._db.execute(f"PRAGMA table_info({table})")}:
                    self._db.execute(f"ALTER TABLE {table} ADD COLUMN flight_id INTEGER")
            row = self._db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
            version = int(row["value"]) if row else 0
            if version > SCHEMA_VERSION:
                raise RuntimeError(f"database {self.path} has schema {version}, newer than this code ({SCHEMA_VERSION})")
            self._db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES('schema_version', ?)", (str(SCHEMA_VERSION),))

    @property
    def schema_version(self) -> int:
        return int(self._db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()["value"])

    def _interrupt_orphans(self) -> int:
        with self._lock:
            cur = self._db.execute(
                "UPDATE jobs SET status='interrupted', error=COALESCE(error, 'service stopped while the job ran'), "
                "updated_at=? WHERE status IN ('running', 'queued')", (self._clock(),))
            if cur.rowcount:
                log.warning("%d job(s) were running when the service last stopped: marked interrupted", cur.rowcount)
            return cur.rowcount

    def _seed_builtins(self) -> None:
        with self._lock:
            for name, ps in BUILTIN_SETS.items():
                self._db.execute(
                    "INSERT OR IGNORE INTO parameter_sets(name, body, provenance, builtin, active, created_at) "
                    "VALUES(?, ?, ?, 1, 0, ?)",
                    (name, ps.to_json(), _dumps({"source": "builtin", **dict(ps.provenance)}), self._clock()))

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # --- parameter sets ------------------------------------------------------------------------

    def parameter_sets(self) -> list[dict]:
        rows = self._db.execute("SELECT name, provenance, builtin, active, created_at, body FROM parameter_sets ORDER BY created_at, name").fetchall()
        out = []
        for r in rows:
            body = json.loads(r["body"])
            out.append({"name": r["name"], "builtin": bool(r["builtin"]), "active": bool(r["active"]),
                        "physical": bool(body.get("physical", True)), "description": body.get("description", ""),
                        "provenance": json.loads(r["provenance"]), "created_at": r["created_at"]})
        return out

    def parameter_set(self, name: str) -> ParameterSet:
        row = self._db.execute("SELECT body, provenance FROM parameter_sets WHERE name=?", (name,)).fetchone()
        if row is None:
            raise NotFound(f"parameter set {name!r}")
        ps = ParameterSet.from_json(row["body"])
        return ps.replace(provenance=json.loads(row["provenance"]))

    def save_parameter_set(self, ps: ParameterSet, provenance: dict | None = None, overwrite: bool = False) -> None:
        prov = {**dict(ps.provenance), **(provenance or {})}
        with self._lock:
            row = self._db.execute("SELECT builtin FROM parameter_sets WHERE name=?", (ps.name,)).fetchone()
            if row is not None and (row["builtin"] or not overwrite):
                raise Conflict(f"name: parameter set {ps.name!r} exists" + (" (built-in)" if row["builtin"] else ""))
            self._db.execute(
                "INSERT OR REPLACE INTO parameter_sets(name, body, provenance, builtin, active, created_at) "
                "VALUES(?, ?, ?, 0, COALESCE((SELECT active FROM parameter_sets WHERE name=?), 0), ?)",
                (ps.name, ps.to_json(), _dumps(prov), ps.name, self._clock()))

    def activate_parameter_set(self, name: str) -> ParameterSet:
        ps = self.parameter_set(name)
        if not ps.physical:
            raise Conflict(f"name: parameter set {name!r} is a verbatim record, not physical; it cannot be flown")
        with self._lock:
            self._db.execute("BEGIN")
            self._db.execute("UPDATE parameter_sets SET active=0")
            self._db.execute("UPDATE parameter_sets SET active=1 WHERE name=?", (name,))
            self._db.execute("COMMIT")
        return ps

    def active_parameter_set_name(self) -> str | None:
        row = self._db.execute("SELECT name FROM parameter_sets WHERE active=1").fetchone()
        return row["name"] if row else None

    # --- jobs ----------------------------------------------------------------------------------

    def create_job(self, kind: str, request: dict) -> str:
        job_id = uuid.uuid4().hex[:12]
        now = self._clock()
        with self._lock:
            self._db.execute(
                "INSERT INTO jobs(id, kind, status, progress, stage, request, created_at, updated_at) "
                "VALUES(?, ?, 'queued', 0, 'queued', ?, ?, ?)", (job_id, kind, _dumps(request), now, now))
        return job_id

    def update_job(self, job_id: str, *, status: str | None = None, progress: float | None = None,
                   stage: str | None = None, result: Any = None, error: str | None = None) -> None:
        sets, args = ["updated_at=?"], [self._clock()]
        for col, val in (("status", status), ("progress", progress), ("stage", stage), ("error", error)):
            if val is not None:
                sets.append(f"{col}=?")
                args.append(val)
        if result is not None:
            sets.append("result=?")
            args.append(_dumps(result))
        with self._lock:
            cur = self._db.execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id=?", (*args, job_id))
        if cur.rowcount == 0:
            raise NotFound(f"job {job_id!r}")

    def job(self, job_id: str) -> dict:
        row = self._db.execute("SELECT * FROM jobs WHERE id=?", (job_id,)).fetchone()
        if row is None:
            raise NotFound(f"job {job_id!r}")
        return _job_row(row)

    def jobs(self, limit: int = 100) -> list[dict]:
        rows = self._db.execute("SELECT * FROM jobs ORDER BY created_at DESC LIMIT ?", (limit,)).fetchall()
        return [_job_row(r) for r in rows]

    # --- faults --------------------------------------------------------------------------------

    def add_fault(self, fault: Fault, source: str, note: str = "") -> int:
        """Store ``fault`` (the diagnoser's or an operator's); the HTTP API shows its ``type`` as
        ``kind`` and its ``component`` as ``target``. Its ``to_dict()`` is kept whole as the detail."""
        body = fault.to_dict()
        if not math.isfinite(body["time_s"]):  # declared before any telemetry: no message time
            body["time_s"] = None
        if note:
            body["note"] = note
        with self._lock:
            cur = self._db.execute(
                "INSERT INTO faults(time_s, kind, target, magnitude, source, active, body, created_at, flight_id) "
                "VALUES(?,?,?,?,?,1,?,?,?)",
                (body["time_s"], fault.type, fault.component, body["magnitude"], source, _dumps(body), self._clock(),
                 self.current_flight_id))
            return int(cur.lastrowid)

    def clear_fault(self, fault_id: int) -> None:
        with self._lock:
            cur = self._db.execute("UPDATE faults SET active=0 WHERE id=?", (fault_id,))
        if cur.rowcount == 0:
            raise NotFound(f"fault {fault_id}")

    def faults(self, active_only: bool = False, flight_id: int | None = None) -> list[dict]:
        where, args = [], []
        if active_only:
            where.append("active=1")
        if flight_id is not None:
            where.append("flight_id=?")
            args.append(flight_id)
        q = "SELECT * FROM faults" + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY id"
        return [{"id": r["id"], "time_s": r["time_s"], "kind": r["kind"], "target": r["target"],
                 "magnitude": r["magnitude"], "source": r["source"], "active": bool(r["active"]),
                 "detail": json.loads(r["body"]), "created_at": r["created_at"], "flight_id": r["flight_id"]}
                for r in self._db.execute(q, args).fetchall()]

    def end_flight_faults(self, flight_id: int) -> list[int]:
        """A flight ended: its active faults (and any of an earlier flight) stop being active; they
        stay in its history. Their ids."""
        with self._lock:
            rows = self._db.execute("SELECT id FROM faults WHERE active=1 AND flight_id IS NOT NULL AND flight_id<=?",
                                    (flight_id,)).fetchall()
            ids = [int(r["id"]) for r in rows]
            self._db.executemany("UPDATE faults SET active=0 WHERE id=?", [(i,) for i in ids])
            return ids

    # --- flights -------------------------------------------------------------------------------

    def begin_flight(self, started_s: float, reason: str, body: dict | None = None) -> tuple[int, list[int], list[int]]:
        """A new flight: no fault of an earlier flight stays active, nor one stored before this store
        was opened (a previous run's, or from before flights were recorded); a fault declared on the
        ground since (no flight open) is the operator's for this flight and joins it.
        (flight id, fault ids closed, fault ids carried in)."""
        with self._lock:
            stale = [int(r["id"]) for r in self._db.execute(
                "SELECT id FROM faults WHERE active=1 AND (flight_id IS NOT NULL OR created_at<?)",
                (self.opened_at,)).fetchall()]
            self._db.executemany("UPDATE faults SET active=0 WHERE id=?", [(i,) for i in stale])
            cur = self._db.execute(
                "INSERT INTO flights(started_s, last_s, begin_reason, body, created_at) VALUES(?,?,?,?,?)",
                (started_s, started_s, reason, _dumps(body or {}), self._clock()))
            fid = int(cur.lastrowid)
            carried = [int(r["id"]) for r in self._db.execute(
                "SELECT id FROM faults WHERE active=1 AND flight_id IS NULL").fetchall()]
            self._db.executemany("UPDATE faults SET flight_id=? WHERE id=?", [(fid, i) for i in carried])
            self.current_flight_id = fid
            return fid, stale, carried

    def touch_flight(self, flight_id: int, last_s: float) -> None:
        with self._lock:
            self._db.execute("UPDATE flights SET last_s=MAX(last_s, ?) WHERE id=?", (last_s, flight_id))

    def end_flight(self, flight_id: int, ended_s: float | None, reason: str) -> None:
        with self._lock:
            self._db.execute("UPDATE flights SET ended_s=COALESCE(?, last_s), end_reason=?, ended_at=? "
                             "WHERE id=? AND ended_s IS NULL", (ended_s, reason, self._clock(), flight_id))
            if self.current_flight_id == flight_id:
                self.current_flight_id = None

    def open_flight(self) -> dict | None:
        """The newest flight not ended (the service stopped during it), or None."""
        row = self._db.execute("SELECT * FROM flights WHERE ended_s IS NULL ORDER BY id DESC LIMIT 1").fetchone()
        return _flight_row(row) if row else None

    def flight(self, flight_id: int) -> dict:
        row = self._db.execute("SELECT * FROM flights WHERE id=?", (flight_id,)).fetchone()
        if row is None:
            raise NotFound(f"flight {flight_id}")
        out = _flight_row(row)
        out["faults"] = self.faults(flight_id=flight_id)
        out["plans"] = [_plan_row(r) for r in self._db.execute(
            "SELECT * FROM plans WHERE flight_id=? ORDER BY id", (flight_id,)).fetchall()]
        out["uploads"] = [_upload_row(r) for r in self._db.execute(
            "SELECT * FROM uploads WHERE flight_id=? ORDER BY id", (flight_id,)).fetchall()]
        return out

    def flights(self, limit: int = 100) -> list[dict]:
        rows = self._db.execute("SELECT * FROM flights ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
        return [_flight_row(r) for r in rows]

    def set_flight_body(self, flight_id: int, **fields) -> None:
        with self._lock:
            row = self._db.execute("SELECT body FROM flights WHERE id=?", (flight_id,)).fetchone()
            if row is None:
                raise NotFound(f"flight {flight_id}")
            body = {**json.loads(row["body"]), **fields}
            self._db.execute("UPDATE flights SET body=? WHERE id=?", (_dumps(body), flight_id))

    # --- plans and uploads ---------------------------------------------------------------------

    def add_plan(self, body: dict, trigger: str, status: str, time_s: float | None) -> int:
        now = self._clock()
        with self._lock:
            cur = self._db.execute(
                "INSERT INTO plans(time_s, trigger, status, body, created_at, updated_at, flight_id) "
                "VALUES(?,?,?,?,?,?,?)", (time_s, trigger, status, _dumps(body), now, now, self.current_flight_id))
            return int(cur.lastrowid)

    def set_plan_status(self, plan_id: int, status: str, note: str | None = None) -> None:
        with self._lock:
            row = self._db.execute("SELECT body FROM plans WHERE id=?", (plan_id,)).fetchone()
            if row is None:
                raise NotFound(f"plan {plan_id}")
            body = json.loads(row["body"])
            body.setdefault("history", []).append({"status": status, "at": self._clock(), "note": note})
            self._db.execute("UPDATE plans SET status=?, body=?, updated_at=? WHERE id=?",
                             (status, _dumps(body), self._clock(), plan_id))

    def transition_plan(self, plan_id: int, from_status: str, to_status: str, note: str | None = None) -> bool:
        """Set the plan's status to ``to_status`` only if it is ``from_status`` now (atomically); whether it was."""
        with self._lock:
            row = self._db.execute("SELECT body FROM plans WHERE id=? AND status=?", (plan_id, from_status)).fetchone()
            if row is None:
                return False
            body = json.loads(row["body"])
            body.setdefault("history", []).append({"status": to_status, "at": self._clock(), "note": note})
            cur = self._db.execute("UPDATE plans SET status=?, body=?, updated_at=? WHERE id=? AND status=?",
                                   (to_status, _dumps(body), self._clock(), plan_id, from_status))
            return cur.rowcount == 1

    def plan(self, plan_id: int) -> dict:
        row = self._db.execute("SELECT * FROM plans WHERE id=?", (plan_id,)).fetchone()
        if row is None:
            raise NotFound(f"plan {plan_id}")
        return _plan_row(row)

    def plans(self, status: str | None = None, limit: int = 100) -> list[dict]:
        if status:
            rows = self._db.execute("SELECT * FROM plans WHERE status=? ORDER BY id DESC LIMIT ?", (status, limit)).fetchall()
        else:
            rows = self._db.execute("SELECT * FROM plans ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
        return [_plan_row(r) for r in rows]

    def add_upload(self, plan_id: int | None, status: str, body: dict) -> int:
        with self._lock:
            cur = self._db.execute("INSERT INTO uploads(plan_id, status, body, created_at, flight_id) "
                                   "VALUES(?,?,?,?,?)",
                                   (plan_id, status, _dumps(body), self._clock(), self.current_flight_id))
            return int(cur.lastrowid)

    #: an upload whose transfer began and whose outcome is not written yet (see begin_upload)
    UPLOAD_INTENT = "intent"

    def begin_upload(self, plan_id: int | None, body: dict) -> int:
        """Record an upload's intent (plan, items, time) before the transfer starts, so a crash
        mid-transfer leaves a record to recover at the next start; :meth:`finish_upload` ends it."""
        return self.add_upload(plan_id, self.UPLOAD_INTENT, body)

    def finish_upload(self, upload_id: int, status: str, body: dict) -> None:
        """An upload's outcome: its status and the full body (replacing the intent's)."""
        with self._lock:
            self._db.execute("UPDATE uploads SET status=?, body=? WHERE id=?", (status, _dumps(body), upload_id))

    def unfinished_uploads(self) -> list[dict]:
        """Intents without an outcome: the service stopped during their transfer."""
        rows = self._db.execute("SELECT * FROM uploads WHERE status=? ORDER BY id", (self.UPLOAD_INTENT,)).fetchall()
        return [_upload_row(r) for r in rows]

    def uploads(self, limit: int = 100) -> list[dict]:
        rows = self._db.execute("SELECT * FROM uploads ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
        return [_upload_row(r) for r in rows]

    # --- files and tlogs -----------------------------------------------------------------------

    def add_file(self, filename: str, path: str, kind: str, size_bytes: int) -> str:
        file_id = uuid.uuid4().hex[:12]
        with self._lock:
            self._db.execute("INSERT INTO files(id, filename, path, kind, size_bytes, created_at) VALUES(?,?,?,?,?,?)",
                             (file_id, filename, path, kind, size_bytes, self._clock()))
        return file_id

    def _one(self, sql: str, key: Any, what: str) -> dict:
        """The one row ``sql`` selects for ``key``; NotFound(``what``) when there is none."""
        row = self._db.execute(sql, (key,)).fetchone()
        if row is None:
            raise NotFound(what)
        return dict(row)

    def file(self, file_id: str) -> dict:
        return self._one("SELECT * FROM files WHERE id=?", file_id, f"file {file_id!r}")

    def files(self) -> list[dict]:
        return [dict(r) for r in self._db.execute("SELECT * FROM files ORDER BY created_at").fetchall()]

    def add_tlog(self, path: str, note: str | None = None) -> int:
        with self._lock:
            self._db.execute("INSERT OR IGNORE INTO tlogs(path, started_at, note) VALUES(?,?,?)", (path, self._clock(), note))
            return int(self._db.execute("SELECT id FROM tlogs WHERE path=?", (path,)).fetchone()["id"])

    def close_tlog(self, tlog_id: int) -> None:
        path = Path(self._one("SELECT path FROM tlogs WHERE id=?", tlog_id, f"tlog {tlog_id}")["path"])
        size = path.stat().st_size if path.exists() else None
        with self._lock:
            self._db.execute("UPDATE tlogs SET ended_at=?, size_bytes=? WHERE id=?", (self._clock(), size, tlog_id))

    def tlog(self, tlog_id: int) -> dict:
        return self._one("SELECT * FROM tlogs WHERE id=?", tlog_id, f"tlog {tlog_id}")

    def tlogs(self) -> list[dict]:
        return [dict(r) for r in self._db.execute("SELECT * FROM tlogs ORDER BY id").fetchall()]

    def index_tlogs(self, paths: Iterable[Path], note: str = "indexed") -> int:
        n = 0
        for p in paths:
            tid = self.add_tlog(str(p), note)
            self.close_tlog(tid)
            n += 1
        return n


def _job_row(r: sqlite3.Row) -> dict:
    return {"id": r["id"], "kind": r["kind"], "status": r["status"], "progress": r["progress"], "stage": r["stage"],
            "request": json.loads(r["request"]), "result": json.loads(r["result"]) if r["result"] else None,
            "error": r["error"], "created_at": r["created_at"], "updated_at": r["updated_at"]}


def _upload_row(r: sqlite3.Row) -> dict:
    return {"id": r["id"], "plan_id": r["plan_id"], "status": r["status"], "created_at": r["created_at"],
            **json.loads(r["body"])}


def _flight_row(r: sqlite3.Row) -> dict:
    return {"id": r["id"], "started_s": r["started_s"], "last_s": r["last_s"], "ended_s": r["ended_s"],
            "begin_reason": r["begin_reason"], "end_reason": r["end_reason"], "open": r["ended_s"] is None,
            "created_at": r["created_at"], "ended_at": r["ended_at"], **json.loads(r["body"])}


def _plan_row(r: sqlite3.Row) -> dict:
    return {"id": r["id"], "time_s": r["time_s"], "trigger": r["trigger"], "status": r["status"],
            "created_at": r["created_at"], "updated_at": r["updated_at"], **json.loads(r["body"])}
