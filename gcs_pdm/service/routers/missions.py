"""``/missions/...``: the vehicle's mission, plans (approve, reject), uploads (revert), replan, refresh."""
from __future__ import annotations

from fastapi import APIRouter, Query

from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, RowId, ServiceDep, finite

router = APIRouter(prefix="/missions")


@router.get("/current", response_model=S.MissionOut)
def current_mission(service: ServiceDep):
    return finite(service.current_mission())


@router.get("/proposed", response_model=list[S.PlanOut])
def proposed(service: ServiceDep):
    """Each proposal with its ``gate``: its age, whether Approve/Reject are refused now (``blocked``,
    link lost, vehicle failed or on the ground) and whether Approve re-plans first (``stale``)."""
    plans = service.store.plans(status="proposed")
    if service.loop is not None:
        plans = [{**p, "gate": service.loop.proposal_gate(p).to_dict()} for p in plans]
    return finite(plans)


@router.get("/plans/{plan_id}", response_model=S.PlanOut, responses=S.errors(404, 422))
def plan(plan_id: RowId, service: ServiceDep):
    return finite(service.store.plan(plan_id))


@router.post("/plans/{plan_id}/approve", response_model=S.PlanOut, dependencies=AUTH,
             responses=S.errors(401, 404, 409, 422))
def approve(plan_id: RowId, service: ServiceDep, body: S.Decision | None = None):
    service.approve(plan_id, (body or S.Decision()).note)
    return finite(service.store.plan(plan_id))


@router.post("/plans/{plan_id}/reject", response_model=S.PlanOut, dependencies=AUTH,
             responses=S.errors(401, 404, 409, 422))
def reject(plan_id: RowId, service: ServiceDep, body: S.Decision | None = None):
    service.reject(plan_id, (body or S.Decision()).note)
    return finite(service.store.plan(plan_id))


@router.get("/history", response_model=list[S.PlanOut], responses=S.errors(422))
def history(service: ServiceDep, limit: int = Query(100, ge=1, le=1000)):
    return finite(service.store.plans(limit=limit))


@router.get("/uploads", response_model=list[S.UploadOut], responses=S.errors(422))
def uploads(service: ServiceDep, limit: int = Query(100, ge=1, le=1000)):
    return finite(service.store.uploads(limit=limit))


@router.post("/uploads/{upload_id}/revert", response_model=S.PlanOut, status_code=202, dependencies=AUTH,
             responses=S.errors(401, 404, 409, 422))
def revert(upload_id: RowId, service: ServiceDep, body: S.Decision | None = None):
    """Upload again the mission that this upload replaced (the operator's choice; not re-planned)."""
    pid = service.revert_upload(upload_id, (body or S.Decision()).note)
    return finite(service.store.plan(pid))


@router.post("/replan", response_model=S.JobCreated, status_code=202, dependencies=AUTH,
             responses=S.errors(401, 409))
def replan(service: ServiceDep):
    service.request_replan("operator")
    return S.JobCreated(id="replan", status="requested")


@router.post("/refresh", response_model=S.JobCreated, status_code=202, dependencies=AUTH,
             responses=S.errors(401, 409))
def refresh(service: ServiceDep):
    """Download the vehicle's mission again (after a ground station changed it)."""
    service.refresh_mission()
    return S.JobCreated(id="refresh", status="requested")
