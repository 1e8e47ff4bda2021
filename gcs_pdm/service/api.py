"""The HTTP API (FastAPI). Reads are open; anything that changes state needs the bearer token.

``create_app(service)`` takes a :class:`gcs_pdm.service.runtime.Service`, so tests build one on a
temporary database without any MAVLink link. See docs/api.md for every endpoint.
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import secrets
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, File, HTTPException, Query, Request, UploadFile
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

import gcs_pdm
from gcs_pdm.models.params import ParameterError, ParameterSet
from gcs_pdm.service import schemas as S
from gcs_pdm.service.console_routes import include_console
from gcs_pdm.service.storage import Conflict, NotFound

log = logging.getLogger(__name__)

UPLOAD_KINDS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".tlog": "tlog"}
MAX_UPLOAD_BYTES = 512 * 1024 * 1024


def _finite(obj: Any) -> Any:
    """JSON has no NaN: MAVLink's NaN params ("unchanged") become null."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj


def _unprocessable(field: str, message: str) -> HTTPException:
    # Same shape as FastAPI's own validation errors, so clients parse one format.
    return HTTPException(422, detail=[{"loc": ["body", *field.split(".")], "msg": message, "type": "value_error"}])


def create_app(service) -> FastAPI:
    app = FastAPI(title="gcs-pdm", version=gcs_pdm.__version__,
                  description="Prognostic decision making beside a MAVLink ground station",
                  docs_url=None, redoc_url=None)  # /docs is the console's, served without a CDN
    include_console(app, service)
    bearer = HTTPBearer(auto_error=False)

    def require_token(cred: HTTPAuthorizationCredentials | None = Depends(bearer)) -> None:
        if cred is None or cred.scheme.lower() != "bearer" or not secrets.compare_digest(
                cred.credentials.encode(), service.token.encode()):
            raise HTTPException(401, detail="missing or wrong bearer token", headers={"WWW-Authenticate": "Bearer"})

    auth = [Depends(require_token)]

    @app.exception_handler(NotFound)
    async def _not_found(_req: Request, exc: NotFound):
        return JSONResponse(status_code=404, content={"detail": f"not found: {exc.args[0]}"})

    @app.exception_handler(Conflict)
    async def _conflict(_req: Request, exc: Conflict):
        return JSONResponse(status_code=409, content={"detail": str(exc)})

    # --- health and status -----------------------------------------------------------------------

    @app.get("/health", response_model=S.Health)
    def health():
        return S.Health(status="ok", version=gcs_pdm.__version__, schema_version=service.store.schema_version,
                        link_connected=bool(service.state.get("link")["connected"]), policy=service.policy,
                        active_parameter_set=service.store.active_parameter_set_name(),
                        interrupted_jobs_at_start=service.store.interrupted_at_open)

    @app.get("/status", response_model=S.VehicleStatus)
    def status():
        return _finite(service.state.snapshot())

    # --- faults ----------------------------------------------------------------------------------

    @app.get("/faults", response_model=list[S.FaultOut])
    def faults(active: bool = False):
        return service.store.faults(active_only=active)

    @app.post("/faults", response_model=S.FaultOut, status_code=201, dependencies=auth)
    def declare_fault(body: S.FaultIn):
        fid = service.declare_fault(body.kind, body.motor, body.magnitude, body.note, replan=body.replan)
        return next(f for f in service.store.faults() if f["id"] == fid)

    @app.post("/faults/{fault_id}/clear", response_model=S.FaultOut, dependencies=auth)
    def clear_fault(fault_id: int):
        service.clear_fault(fault_id)
        return next(f for f in service.store.faults() if f["id"] == fault_id)

    # --- missions --------------------------------------------------------------------------------

    @app.get("/missions/current", response_model=S.MissionOut)
    def current_mission():
        return _finite(service.current_mission())

    @app.get("/missions/proposed", response_model=list[S.PlanOut])
    def proposed():
        return _finite(service.store.plans(status="proposed"))

    @app.get("/missions/plans/{plan_id}", response_model=S.PlanOut)
    def plan(plan_id: int):
        return _finite(service.store.plan(plan_id))

    @app.post("/missions/plans/{plan_id}/approve", response_model=S.PlanOut, dependencies=auth)
    def approve(plan_id: int, body: S.Decision | None = None):
        service.approve(plan_id, (body or S.Decision()).note)
        return _finite(service.store.plan(plan_id))

    @app.post("/missions/plans/{plan_id}/reject", response_model=S.PlanOut, dependencies=auth)
    def reject(plan_id: int, body: S.Decision | None = None):
        service.reject(plan_id, (body or S.Decision()).note)
        return _finite(service.store.plan(plan_id))

    @app.get("/missions/history", response_model=list[S.PlanOut])
    def history(limit: int = Query(100, ge=1, le=1000)):
        return _finite(service.store.plans(limit=limit))

    @app.get("/missions/uploads", response_model=list[S.UploadOut])
    def uploads(limit: int = Query(100, ge=1, le=1000)):
        return _finite(service.store.uploads(limit=limit))

    @app.post("/missions/uploads/{upload_id}/revert", response_model=S.PlanOut, status_code=202, dependencies=auth)
    def revert(upload_id: int, body: S.Decision | None = None):
        """Upload again the mission that this upload replaced (the operator's choice; not re-planned)."""
        pid = service.revert_upload(upload_id, (body or S.Decision()).note)
        return _finite(service.store.plan(pid))

    @app.post("/missions/replan", response_model=S.JobCreated, status_code=202, dependencies=auth)
    def replan():
        service.request_replan("operator")
        return S.JobCreated(id="replan", status="requested")

    @app.post("/missions/refresh", response_model=S.JobCreated, status_code=202, dependencies=auth)
    def refresh():
        """Download the vehicle's mission again (after a ground station changed it)."""
        service.refresh_mission()
        return S.JobCreated(id="refresh", status="requested")

    @app.get("/policy", response_model=S.PolicyIn)
    def get_policy():
        return S.PolicyIn(policy=service.policy)

    @app.put("/policy", response_model=S.PolicyIn, dependencies=auth)
    def set_policy(body: S.PolicyIn):
        service.set_policy(body.policy)
        return S.PolicyIn(policy=service.policy)

    # --- parameter sets --------------------------------------------------------------------------

    @app.get("/parameter-sets", response_model=list[S.ParameterSetSummary])
    def parameter_sets():
        return service.store.parameter_sets()

    @app.get("/parameter-sets/{name}")
    def parameter_set(name: str) -> dict:
        """The full set as JSON (the export format; ``POST /parameter-sets`` imports it)."""
        return service.store.parameter_set(name).to_dict()

    @app.post("/parameter-sets", response_model=S.ParameterSetSummary, status_code=201, dependencies=auth)
    def import_parameter_set(body: S.ParameterSetImport):
        data = dict(body.parameter_set)
        if body.name:
            data["name"] = body.name
        if not data.get("name"):
            raise _unprocessable("name", "a name is required (in the body or the set)")
        try:
            ps = ParameterSet.from_dict(data)
        except (ParameterError, ValueError) as exc:
            raise _unprocessable("parameter_set." + _field_of(str(exc)), str(exc)) from None
        service.store.save_parameter_set(ps, provenance={"source": "import"}, overwrite=body.overwrite)
        if body.activate:
            service.activate_parameter_set(ps.name)
        return next(p for p in service.store.parameter_sets() if p["name"] == ps.name)

    @app.post("/parameter-sets/{name}/activate", response_model=S.ParameterSetSummary, dependencies=auth)
    def activate(name: str):
        service.activate_parameter_set(name)
        return next(p for p in service.store.parameter_sets() if p["name"] == name)

    # --- flight files and tlogs ------------------------------------------------------------------

    @app.post("/files", response_model=S.FileOut, status_code=201, dependencies=auth)
    async def upload_file(file: UploadFile = File(...)):
        name = Path(file.filename or "").name
        kind = UPLOAD_KINDS.get(Path(name).suffix.lower())
        if not name or kind is None:
            raise _unprocessable("file", f"expected a .csv, .parquet or .tlog file, got {name!r}")
        data = await file.read(MAX_UPLOAD_BYTES + 1)
        if len(data) > MAX_UPLOAD_BYTES:
            raise HTTPException(413, detail=f"file: larger than {MAX_UPLOAD_BYTES} bytes")
        if not data:
            raise _unprocessable("file", "empty file")
        problem = await asyncio.to_thread(service.check_upload, name, kind, data)
        if problem:
            raise _unprocessable("file", problem)
        file_id = service.save_upload(name, kind, data)
        return service.store.file(file_id)

    @app.get("/files", response_model=list[S.FileOut])
    def files():
        return service.store.files()

    @app.get("/tlogs", response_model=list[S.TlogOut])
    def tlogs():
        return service.store.tlogs()

    # --- jobs ------------------------------------------------------------------------------------

    @app.post("/jobs/fit", response_model=S.JobCreated, status_code=202, dependencies=auth)
    def fit(body: S.FitJobIn):
        try:
            service.store.parameter_set(body.base_set)
        except NotFound:
            raise _unprocessable("base_set", f"no parameter set {body.base_set!r}") from None
        for split in ("train", "validation", "test"):
            for i, ref in enumerate(getattr(body.flights, split)):
                problem = service.check_flight_ref(ref)
                if problem:
                    raise _unprocessable(f"flights.{split}.{i}", problem)
        from gcs_pdm.service.fit_jobs import check_save_as, check_settings

        problem = check_save_as(service, body.save_as, body.overwrite)
        if problem:
            raise _unprocessable("save_as", problem)

        bad = check_settings(body.settings)
        if bad:
            raise _unprocessable(*bad)
        job_id = service.runner.submit("fit", body.model_dump())
        return S.JobCreated(id=job_id, status="queued")

    @app.get("/jobs", response_model=list[S.JobOut])
    def jobs(limit: int = Query(100, ge=1, le=1000)):
        return _finite(service.store.jobs(limit))

    @app.get("/jobs/{job_id}", response_model=S.JobOut)
    def job(job_id: str):
        return _finite(service.store.job(job_id))

    @app.post("/jobs/{job_id}/cancel", response_model=S.JobOut, dependencies=auth)
    def cancel(job_id: str):
        return _finite(service.runner.cancel(job_id))

    @app.get("/jobs/{job_id}/result")
    def job_result(job_id: str) -> dict:
        job = service.store.job(job_id)
        if job["status"] != "succeeded":
            raise HTTPException(409, detail=f"job {job_id} is {job['status']}, no result")
        return _finite(job["result"])

    @app.get("/jobs/{job_id}/plots/{name}", response_class=FileResponse)
    def job_plot(job_id: str, name: str):
        job = service.store.job(job_id)
        plots = (job["result"] or {}).get("plots", {})
        if name not in plots:
            raise NotFound(f"plot {name!r} of job {job_id}")
        return FileResponse(plots[name], media_type="image/png")

    # --- live updates ----------------------------------------------------------------------------

    @app.get("/events/poll")
    def events_poll(since: int = Query(0, ge=0)) -> list[dict]:
        return [_finite(e.to_dict()) for e in service.events.since(since)]

    @app.get("/events")
    async def events(request: Request, since: int | None = Query(None, ge=0)):
        """Server-Sent Events: one ``event: <kind>`` per fault, plan, upload, job change, status tick."""
        start = since
        if start is None:
            header = request.headers.get("last-event-id", "").strip()
            start = int(header) if header.isdigit() else service.events.last_seq

        async def stream():
            seq = start
            yield ": connected\n\n"
            while not await request.is_disconnected():
                batch = await asyncio.to_thread(service.events.wait, seq, 1.0)
                if not batch:
                    yield ": keep-alive\n\n"
                    continue
                for ev in batch:
                    seq = ev.seq
                    yield f"id: {ev.seq}\nevent: {ev.kind}\ndata: {json.dumps(_finite(ev.to_dict()))}\n\n"

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    return app


def _field_of(message: str) -> str:
    """ParameterError messages start with the dotted field ('packs.LLF20.battery.R_s: ...')."""
    head = message.split(":", 1)[0]
    return head if head and " " not in head else "parameter_set"
