"""``/packs``: each pack's health across flights, its trend and retirement forecast
(gcs_pdm.packs; docs/packs.md); the operator's slot assignments."""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, Field

from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, PathName, ServiceDep, finite

router = APIRouter(prefix="/packs")


class AssignIn(BaseModel):
    slot: str = Field(min_length=1, max_length=128, description="the slot (a vehicle description's pack name, battery<N>)")
    pack_id: str = Field(min_length=1, max_length=128, description="the pack now in the slot")
    note: str = Field("", max_length=500)


def _thresholds(service) -> dict:
    c = service.config
    return {"capacity_fraction": c.pack_retire_capacity_fraction, "resistance_factor": c.pack_retire_resistance_factor}


@router.get("", response_model=list[dict[str, Any]])
def packs(service: ServiceDep):
    out = []
    for pid in service.packs.pack_ids():
        s = service.packs.summary(pid, **_thresholds(service))
        out.append({k: s[k] for k in ("pack_id", "flights", "identity", "slots", "warning", "equivalent_cycles",
                                      "latest", "thresholds")} | {"retirement": s["trend"]["retirement"]})
    return finite(out)


@router.get("/assignments", response_model=dict[str, Any])
def assignments(service: ServiceDep):
    return service.packs.assignments()


@router.get("/priors", response_model=dict[str, Any])
def priors(service: ServiceDep):
    """Per pack slot: what the next flight's estimator should start from (latest capacity and
    resistance at 25 °C with σ), or null."""
    return finite(service.pack_priors())


@router.put("/assignments", response_model=dict[str, Any], dependencies=AUTH, responses=S.errors(401, 422))
def assign(body: AssignIn, service: ServiceDep):
    return service.packs.assign(body.slot, body.pack_id, body.note)


@router.delete("/assignments/{slot}", response_model=dict[str, Any], dependencies=AUTH,
               responses=S.errors(401, 404, 422))
def unassign(slot: PathName, service: ServiceDep):
    """The slot's assignment removed (returned): its pack is again known by serial or slot name."""
    row = service.packs.assignments().get(slot)
    if row is None or not service.packs.unassign(slot):
        raise HTTPException(404, detail=f"not found: no assignment for slot {slot!r}")
    return row


@router.get("/{pack_id}", response_model=dict[str, Any], responses=S.errors(404, 422))
def pack(pack_id: PathName, service: ServiceDep):
    try:
        return finite(service.packs.summary(pack_id, **_thresholds(service)))
    except KeyError:
        raise HTTPException(404, detail=f"not found: pack {pack_id!r}") from None
