"""``/flights``: flights as records (service/flights.py): each with its faults, plans and uploads;
the operator carries a motor fault of an earlier flight into the present one."""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from pydantic import BaseModel, Field

from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, RowId, ServiceDep, finite

router = APIRouter(prefix="/flights")


class CarryOverIn(BaseModel):
    fault_id: int = Field(ge=1, le=S.SQLITE_INT_MAX, description="a motor fault of an earlier flight")
    note: str = Field("", max_length=500)


@router.get("", response_model=list[dict[str, Any]], responses=S.errors(422))
def flights(service: ServiceDep, limit: int = 100):
    return finite(service.store.flights(limit=max(1, min(limit, 10000))))


@router.get("/{flight_id}", response_model=dict[str, Any], responses=S.errors(404, 422))
def flight(flight_id: RowId, service: ServiceDep):
    return finite(service.store.flight(flight_id))


@router.post("/carry-over", response_model=S.FaultOut, status_code=201, dependencies=AUTH,
             responses=S.errors(401, 404, 409, 422))
def carry_over(body: CarryOverIn, service: ServiceDep):
    fid = service.carry_over_fault(body.fault_id, body.note)
    return next(f for f in service.store.faults() if f["id"] == fid)
