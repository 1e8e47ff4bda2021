"""The operator's console: the page at ``/``, its static files, Swagger UI at ``/docs``, and the
little read-only JSON the page needs that the rest of the API does not give.

Everything the browser loads comes from the package (``gcs_pdm/service/console/``): the field
laptop has no internet, so nothing may come from a CDN. ``create_app`` includes ``router`` and
turns FastAPI's own CDN-backed ``/docs`` off. See docs/console.md.
"""
from __future__ import annotations

import mimetypes
import os
import secrets
from importlib import resources

from fastapi import APIRouter, HTTPException, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, Response

router = APIRouter()

#: environment variable naming a map tile URL template ({z}/{x}/{y}); until the service config
#: has a ``map_tile_url`` key, this is how a deployment with a tile server turns the tiles on.
TILE_URL_ENV = "GCS_PDM_MAP_TILE_URL"
STATIC_PREFIX = "/console/"
#: names this process, so a page can tell a restarted service (event numbers begin again) from a blip
_PROCESS = secrets.token_hex(6)
_TYPES = {".js": "text/javascript", ".css": "text/css", ".html": "text/html", ".png": "image/png",
          ".svg": "image/svg+xml", ".txt": "text/plain"}


def console_files():
    """The console's static directory as an importlib Traversable (works from a wheel too)."""
    return resources.files("gcs_pdm.service").joinpath("console")


def _asset(path: str) -> tuple[bytes, str]:
    parts = [p for p in path.split("/") if p]
    if not parts or any(p in (".", "..") or p.startswith(".") for p in parts):
        raise HTTPException(404, detail=f"not found: {path}")
    node = console_files()
    for p in parts:
        node = node.joinpath(p)
    if not node.is_file():
        raise HTTPException(404, detail=f"not found: {path}")
    suffix = os.path.splitext(parts[-1])[1].lower()
    media = _TYPES.get(suffix) or mimetypes.guess_type(parts[-1])[0] or "application/octet-stream"
    return node.read_bytes(), media


@router.get("/", response_class=HTMLResponse, include_in_schema=False)
def console_page() -> HTMLResponse:
    body, _ = _asset("index.html")
    return HTMLResponse(body, headers={"Cache-Control": "no-cache"})


@router.get("/docs", include_in_schema=False)
def swagger_ui(request: Request) -> HTMLResponse:
    root = request.scope.get("root_path", "")
    return get_swagger_ui_html(
        openapi_url=root + request.app.openapi_url, title=request.app.title + " API",
        swagger_js_url=root + STATIC_PREFIX + "vendor/swagger-ui/swagger-ui-bundle.js",
        swagger_css_url=root + STATIC_PREFIX + "vendor/swagger-ui/swagger-ui.css",
        swagger_favicon_url=root + STATIC_PREFIX + "vendor/swagger-ui/favicon-32x32.png",
        # no call home to validator.swagger.io
        swagger_ui_parameters={"validatorUrl": None})


def console_settings(service) -> dict:
    """What the page needs to draw limits and the map, read from the running service."""
    from gcs_pdm.planning.scenario import PlanLimits

    limits = service.limits or PlanLimits()
    tile_url = getattr(service.config, "map_tile_url", None) or os.environ.get(TILE_URL_ENV) or None
    return {
        "instance": f"{_PROCESS}-{id(service.events):x}",
        "tile_url": tile_url,
        "tile_attribution": getattr(service.config, "map_tile_attribution", None) or "",
        "limits": {"pack_cutoff_v": limits.pack_cutoff_v, "pack_max_temp_c": limits.pack_max_temp_c,
                   "motor_max_temp_c": limits.motor_max_temp_c,
                   "landing_reserve_soc": limits.landing_reserve_soc},
    }


@router.get("/console/settings", tags=["console"])
def settings(request: Request) -> dict:
    """Map tiles (null: draw in the local east/north frame) and the limits the planner flies to."""
    return console_settings(request.app.state.service)


@router.get(STATIC_PREFIX + "{path:path}", include_in_schema=False)
def console_asset(path: str) -> Response:
    body, media = _asset(path)
    # vendored libraries never change under one version; the page's own files may between releases
    cache = "max-age=86400" if path.startswith("vendor/") else "no-cache"
    return Response(body, media_type=media, headers={"Cache-Control": cache})


def include_console(app, service) -> None:
    """Put the console on ``app``; ``create_app`` calls this (the settings read the service)."""
    app.state.service = service  # the name main's routers.deps reads too
    app.include_router(router)
