"""The HTTP API (FastAPI). Reads are open; anything that changes state needs the bearer token.

``create_app(service)`` takes a :class:`gcs_pdm.service.runtime.Service`, so tests build one on a
temporary database without any MAVLink link. The endpoints live in ``gcs_pdm.service.routers``,
one router per resource; the service and the token check reach them as FastAPI dependencies
(``routers/deps.py``). See docs/api.md for every endpoint.
"""
from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

import gcs_pdm
from gcs_pdm.service.console_routes import include_console
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

    @app.exception_handler(NotFound)
    async def _not_found(_req: Request, exc: NotFound):
        return JSONResponse(status_code=404, content={"detail": f"not found: {exc.args[0]}"})

    @app.exception_handler(Conflict)
    async def _conflict(_req: Request, exc: Conflict):
        return JSONResponse(status_code=409, content={"detail": str(exc)})

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
    return app
