"""The HTTP API (FastAPI). Reads are open; anything that changes state needs the bearer token.

``create_app(service)`` takes a :class:`gcs_pdm.service.runtime.Service`, so tests build one on a
temporary database without any MAVLink link. The endpoints live in ``gcs_pdm.service.routers``,
one router per resource; the service and the token check reach them as FastAPI dependencies
(``routers/deps.py``). See docs/api.md for every endpoint.
"""
from __future__ import annotations

import logging
import sqlite3

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.exceptions import HTTPException as StarletteHTTPException

import gcs_pdm
from gcs_pdm.service.console_routes import include_console
from gcs_pdm.service import schemas as S
from gcs_pdm.service.request_limits import JsonBodyGuard, storage_failure, validation_errors
from gcs_pdm.service.routers import events, faults, files, flights, health, jobs, missions, packs, parameter_sets
from gcs_pdm.service.storage import Conflict, NotFound
from gcs_pdm.service.uploads import UploadBodyLimit

log = logging.getLogger(__name__)

#: every resource's router, in the order they are included
ROUTERS = (health.router, faults.router, missions.router, parameter_sets.router, files.router, jobs.router,
           events.router, flights.router, packs.router)


def create_app(service) -> FastAPI:
    app = FastAPI(title="gcs-pdm", version=gcs_pdm.__version__,
                  description="Prognostic decision making beside a MAVLink ground station",
                  docs_url=None, redoc_url=None)  # /docs is the console's: Swagger UI served without a CDN
    app.state.service = service  # what ``routers.deps.get_service`` hands every endpoint
    app.add_middleware(UploadBodyLimit, path="/files", max_bytes=lambda: service.config.max_upload_bytes)
    app.add_middleware(JsonBodyGuard, max_bytes=lambda: service.config.max_json_bytes, skip_path="/files")

    @app.exception_handler(NotFound)
    async def _not_found(_req: Request, exc: NotFound):
        return JSONResponse(status_code=404, content={"detail": f"not found: {exc.args[0]}"})

    @app.exception_handler(Conflict)
    async def _conflict(_req: Request, exc: Conflict):
        return JSONResponse(status_code=409, content={"detail": str(exc)})

    @app.exception_handler(RequestValidationError)
    async def _invalid(_req: Request, exc: RequestValidationError):
        # FastAPI's shape, but the input is never echoed back beyond a short excerpt
        return JSONResponse(status_code=422, content={"detail": validation_errors(exc.errors())})

    async def _storage(_req: Request, exc: Exception):
        reason = storage_failure(exc)
        if reason is None:
            raise exc
        log.warning("write refused: %s", reason)
        return JSONResponse(status_code=507, content={"detail": reason})

    app.add_exception_handler(sqlite3.OperationalError, _storage)
    app.add_exception_handler(OSError, _storage)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(req: Request, exc: StarletteHTTPException):
        # FastAPI answers a body it cannot parse (bad UTF-8, broken JSON or multipart) with a 400;
        # it is an invalid body like any other, so it gets the documented 422 and its shape.
        if exc.status_code == 400:
            return JSONResponse(status_code=422, content={"detail": [
                {"loc": ["body"], "msg": str(exc.detail), "type": "value_error"}]})
        return await http_exception_handler(req, exc)

    # the operator's console at /, its assets and the local Swagger UI at /docs (console_routes.py)
    include_console(app, service)

    for router in ROUTERS:
        app.include_router(router)
    for route in app.routes:  # any write can meet a full disk or database
        if isinstance(route, APIRoute) and route.methods & {"POST", "PUT", "PATCH", "DELETE"}:
            route.responses.setdefault(507, S.errors(507)[507])
            route.responses.setdefault(413, {"model": S.ErrorOut, "description": "the request body is larger than "
                                             "max_json_bytes (uploads: max_upload_bytes)"})
    return app
