"""``/parameter-sets``: list, export, import and activate parameter sets."""
from __future__ import annotations

from fastapi import APIRouter

from gcs_pdm.models.params import ParameterError, ParameterSet
from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, PathName, ServiceDep, unprocessable
from gcs_pdm.service.status_report import model_variant_report

router = APIRouter(prefix="/parameter-sets")


@router.get("", response_model=list[S.ParameterSetSummary])
def parameter_sets(service: ServiceDep):
    return service.store.parameter_sets()


@router.get("/{name}", responses=S.errors(404, 422))
def parameter_set(name: PathName, service: ServiceDep) -> dict:
    """The full set as JSON (the export format; ``POST /parameter-sets`` imports it)."""
    return service.store.parameter_set(name).to_dict()


@router.post("", response_model=S.ParameterSetSummary, status_code=201, dependencies=AUTH,
             responses=S.errors(401, 404, 409, 422))
def import_parameter_set(body: S.ParameterSetImport, service: ServiceDep):
    data = dict(body.parameter_set)
    if body.name:
        data["name"] = body.name
    if not data.get("name"):
        raise unprocessable("name", "a name is required (in the body or the set)")
    try:
        ps = ParameterSet.from_dict(data)
    except (ParameterError, ValueError) as exc:
        raise unprocessable("parameter_set." + _field_of(str(exc)), str(exc)) from None
    service.store.save_parameter_set(ps, provenance={"source": "import"}, overwrite=body.overwrite)
    if body.activate:
        service.activate_parameter_set(ps.name)
    return next(p for p in service.store.parameter_sets() if p["name"] == ps.name)


@router.post("/{name}/activate", response_model=S.ParameterSetSummary, dependencies=AUTH,
             responses=S.errors(401, 404, 409, 422))
def activate(name: PathName, service: ServiceDep):
    ps = service.activate_parameter_set(name)
    return {**next(p for p in service.store.parameter_sets() if p["name"] == name),
            "model_variants": model_variant_report(ps)}


def _field_of(message: str) -> str:
    """ParameterError messages start with the dotted field ('packs.LLF20.battery.R_s: ...')."""
    head = message.split(":", 1)[0]
    return head if head and " " not in head else "parameter_set"
