"""What every router shares: the service and the bearer-token check as FastAPI dependencies, and
the two response helpers (JSON without NaN, a validation error in FastAPI's own shape)."""
from __future__ import annotations

import math
import secrets
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Request
from fastapi import Path as PathParam
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from gcs_pdm.service.runtime import Service
from gcs_pdm.service.schemas import SQLITE_INT_MAX


#: a database row id in a path (plans, faults, uploads); out of range is a 422 naming the parameter
RowId = Annotated[int, PathParam(ge=1, le=SQLITE_INT_MAX, description="row id, 1 .. 2^63-1")]

#: a name or id string in a path (jobs, parameter sets, plots): bounded, so no 5 kB key reaches the store
PathName = Annotated[str, PathParam(min_length=1, max_length=128)]


def get_service(request: Request) -> Service:
    """The service this app was created for (``create_app`` puts it on ``app.state``)."""
    return request.app.state.service


ServiceDep = Annotated[Service, Depends(get_service)]

_bearer = HTTPBearer(auto_error=False)


def require_token(service: ServiceDep,
                  cred: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)] = None) -> None:
    """Anything that changes state needs the service's bearer token (reads are open)."""
    if cred is None or cred.scheme.lower() != "bearer" or not secrets.compare_digest(
            cred.credentials.encode(), service.token.encode()):
        raise HTTPException(401, detail="missing or wrong bearer token", headers={"WWW-Authenticate": "Bearer"})


#: ``dependencies=AUTH`` on a route makes it need the token
AUTH = [Depends(require_token)]


def finite(obj: Any) -> Any:
    """JSON has no NaN: MAVLink's NaN params ("unchanged") become null."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [finite(v) for v in obj]
    return obj


def unprocessable(field: str, message: str) -> HTTPException:
    # Same shape as FastAPI's own validation errors, so clients parse one format.
    return HTTPException(422, detail=[{"loc": ["body", *field.split(".")], "msg": message, "type": "value_error"}])
