"""``/faults``: the diagnosed and operator-declared faults; the operator declares and clears."""
from __future__ import annotations

from fastapi import APIRouter

from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, RowId, ServiceDep

router = APIRouter(prefix="/faults")


@router.get("", response_model=list[S.FaultOut], responses=S.errors(422))
def faults(service: ServiceDep, active: bool = False):
    return service.store.faults(active_only=active)


@router.post("", response_model=S.FaultOut, status_code=201, dependencies=AUTH, responses=S.errors(401, 422))
def declare_fault(body: S.FaultIn, service: ServiceDep):
    fid = service.declare_fault(body.kind, body.motor, body.magnitude, body.note, replan=body.replan)
    return next(f for f in service.store.faults() if f["id"] == fid)


@router.post("/{fault_id}/clear", response_model=S.FaultOut, dependencies=AUTH, responses=S.errors(401, 404, 422))
def clear_fault(fault_id: RowId, service: ServiceDep):
    service.clear_fault(fault_id)
    return next(f for f in service.store.faults() if f["id"] == fault_id)
