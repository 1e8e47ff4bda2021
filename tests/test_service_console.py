"""The console's files ship with the package and are served by the service, Swagger UI included,
with no reference to any other host (the field has no internet)."""
from __future__ import annotations

import re
import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import load_config
from gcs_pdm.service.console_routes import TILE_URL_ENV
from gcs_pdm.service.runtime import Service

REPO = Path(__file__).resolve().parents[1]
SHIPPED = ["index.html", "app.js", "app.css", "vendor/leaflet/leaflet.js", "vendor/leaflet/leaflet.css",
           "vendor/leaflet/LICENSE", "vendor/leaflet/images/marker-icon.png", "vendor/swagger-ui/swagger-ui-bundle.js",
           "vendor/swagger-ui/swagger-ui.css", "vendor/swagger-ui/favicon-32x32.png", "vendor/swagger-ui/LICENSE"]


@pytest.fixture
def client(tmp_path, monkeypatch):
    monkeypatch.delenv(TILE_URL_ENV, raising=False)
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="console-test-token-0123456789"))
    with TestClient(create_app(svc)) as c:
        yield c
    svc.close()


def test_console_files_load_through_importlib_resources():
    root = resources.files("gcs_pdm.service").joinpath("console")
    for name in SHIPPED:
        node = root
        for part in name.split("/"):
            node = node.joinpath(part)
        assert node.is_file() and node.read_bytes(), name


def test_page_assets_and_docs_are_served_from_the_service(client):
    page = client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    # every script and stylesheet the page and /docs name is a path on this service, and is served
    docs = client.get("/docs")
    assert docs.status_code == 200
    for html in (page.text, docs.text):
        refs = re.findall(r'(?:src|href)=["\']([^"\']+)["\']', html) + re.findall(r"url: ?'([^']+)'", html)
        assert refs
        for ref in refs:
            if ref.startswith("data:") or ref == "/docs":
                continue
            assert ref.startswith("/"), f"{ref} is not on this service"
            r = client.get(ref)
            assert r.status_code == 200, ref
    assert "cdn.jsdelivr" not in docs.text and "fastapi.tiangolo.com" not in docs.text
    js = client.get("/console/vendor/leaflet/leaflet.js")
    assert js.headers["content-type"].startswith("text/javascript")
    assert client.get("/redoc").status_code == 404  # FastAPI's CDN-backed ReDoc is off too


def test_console_files_never_leave_their_folder(client):
    for bad in ("/console/../api.py", "/console/%2e%2e/api.py", "/console/vendor/../../api.py",
                "/console/.hidden", "/console/", "/console/nothing.js"):
        assert client.get(bad).status_code == 404, bad


def test_the_page_names_no_other_host():
    root = resources.files("gcs_pdm.service").joinpath("console")
    for name in ("index.html", "app.js", "app.css"):
        text = root.joinpath(name).read_text()
        assert not re.search(r"https?://", text), name


def test_settings_give_limits_and_tiles(client, monkeypatch):
    s = client.get("/console/settings").json()
    assert s["tile_url"] is None
    assert s["limits"]["pack_cutoff_v"] > 0 and s["limits"]["motor_max_temp_c"] > 0
    assert s["instance"]
    monkeypatch.setenv(TILE_URL_ENV, "http://tiles.local/{z}/{x}/{y}.png")
    assert client.get("/console/settings").json()["tile_url"] == "http://tiles.local/{z}/{x}/{y}.png"


BUILD_PY = """
import sys
from setuptools.config.pyprojecttoml import apply_configuration
from setuptools.dist import Distribution
dist = Distribution()
dist.script_name = "setup.py"
apply_configuration(dist, "pyproject.toml")
cmd = dist.get_command_obj("build_py")
cmd.build_lib = sys.argv[1]
dist.run_command("build_py")
"""


@pytest.mark.timeout(120)
def test_an_install_carries_the_console(tmp_path):
    # what `pip install .` copies: setuptools' build_py with this pyproject's package data
    out = subprocess.run([sys.executable, "-c", BUILD_PY, str(tmp_path)], cwd=REPO, capture_output=True,
                         text=True, timeout=110)
    assert out.returncode == 0, out.stderr[-2000:]
    for name in SHIPPED:
        assert (tmp_path / "gcs_pdm" / "service" / "console" / name).is_file(), name
