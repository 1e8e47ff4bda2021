"""``/health``, ``/status`` and ``/policy``."""
from __future__ import annotations

from fastapi import APIRouter

import gcs_pdm
from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, ServiceDep, finite
from gcs_pdm.service.fit_envelope import fit_envelope_warnings
from gcs_pdm.service.status_report import foreign_system_ids, health_reasons, link_trust, trust_warnings

router = APIRouter()


@router.get("/health", response_model=S.Health)
def health(service: ServiceDep):
    link = service.state.get("link")
    reasons = [f"link lost: {link.get('reason')}"] if link.get("state") == "lost" else []
    reasons += health_reasons(trust_warnings(link_trust(service)))
    return S.Health(status="degraded" if reasons else "ok", reasons=reasons, version=gcs_pdm.__version__,
                    schema_version=service.store.schema_version,
                    link_connected=bool(link["connected"]), policy=service.policy,
                    active_parameter_set=service.store.active_parameter_set_name(),
                    interrupted_jobs_at_start=service.store.interrupted_at_open,
                    foreign_systems=foreign_system_ids(service),
                    readiness=service.state.get("readiness"), vehicle=service.state.get("vehicle"))


@router.get("/status", response_model=S.VehicleStatus)
def status(service: ServiceDep):
    snapshot, trust = service.state.snapshot(), link_trust(service)
    alarm = (snapshot.get("outlook") or {}).get("alarm")
    warnings = (list(snapshot.get("warnings") or []) + trust_warnings(trust)
                + fit_envelope_warnings(snapshot.get("fit_envelope"))
                + ([{k: alarm[k] for k in ("kind", "level", "title", "text")}] if alarm else []))
    return finite({**snapshot, "link_trust": trust, **({"warnings": warnings} if warnings else {})})


@router.get("/policy", response_model=S.PolicyIn)
def get_policy(service: ServiceDep):
    return S.PolicyIn(policy=service.policy)


@router.put("/policy", response_model=S.PolicyIn, dependencies=AUTH, responses=S.errors(401, 422))
def set_policy(body: S.PolicyIn, service: ServiceDep):
    service.set_policy(body.policy)
    return S.PolicyIn(policy=service.policy)
