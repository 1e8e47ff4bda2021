"""``/jobs``: fit jobs (submit, list, cancel) and their results and plots."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import FileResponse

from gcs_pdm.service import schemas as S
from gcs_pdm.service.fit_jobs import check_save_as, check_settings
from gcs_pdm.service.routers.deps import AUTH, PathName, ServiceDep, finite, unprocessable
from gcs_pdm.service.storage import NotFound

router = APIRouter(prefix="/jobs")


@router.post("/fit", response_model=S.JobCreated, status_code=202, dependencies=AUTH, responses=S.errors(401, 422))
def fit(body: S.FitJobIn, service: ServiceDep):
    try:
        service.store.parameter_set(body.base_set)
    except NotFound:
        raise unprocessable("base_set", f"no parameter set {body.base_set!r}") from None
    for split in ("train", "validation", "test"):
        for i, ref in enumerate(getattr(body.flights, split)):
            problem = service.check_flight_ref(ref)
            if problem:
                raise unprocessable(f"flights.{split}.{i}", problem)
    problem = check_save_as(service, body.save_as, body.overwrite)
    if problem:
        raise unprocessable("save_as", problem)
    bad = check_settings(body.settings)
    if bad:
        raise unprocessable(*bad)
    job_id = service.runner.submit("fit", body.model_dump())
    return S.JobCreated(id=job_id, status="queued")


@router.get("", response_model=list[S.JobOut], responses=S.errors(422))
def jobs(service: ServiceDep, limit: int = Query(100, ge=1, le=1000)):
    return finite(service.store.jobs(limit))


@router.get("/{job_id}", response_model=S.JobOut, responses=S.errors(404, 422))
def job(job_id: PathName, service: ServiceDep):
    return finite(service.store.job(job_id))


@router.post("/{job_id}/cancel", response_model=S.JobOut, dependencies=AUTH, responses=S.errors(401, 404, 409, 422))
def cancel(job_id: PathName, service: ServiceDep):
    return finite(service.runner.cancel(job_id))


@router.get("/{job_id}/result", responses=S.errors(404, 409, 422))
def job_result(job_id: PathName, service: ServiceDep) -> dict:
    job = service.store.job(job_id)
    if job["status"] != "succeeded":
        raise HTTPException(409, detail=f"job {job_id} is {job['status']}, no result")
    return finite(job["result"])


@router.get("/{job_id}/plots/{name}", response_class=FileResponse,
            responses={200: {"content": {"image/png": {}}}, **S.errors(404, 422)})
def job_plot(job_id: PathName, name: PathName, service: ServiceDep):
    job = service.store.job(job_id)
    plots = (job["result"] or {}).get("plots", {})
    if name not in plots:
        raise NotFound(f"plot {name!r} of job {job_id}")
    return FileResponse(plots[name], media_type="image/png")
