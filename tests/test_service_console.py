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


def test_settings_give_limits_and_tiles(client, tmp_path):
    s = client.get("/console/settings").json()
    assert s["tile_url"] is None
    assert s["limits"]["pack_cutoff_v"] > 0 and s["limits"]["motor_max_temp_c"] > 0
    assert s["instance"]
    # the map_tile_url config key (its environment variable here) turns the tiles on
    url = "http://tiles.local/{z}/{x}/{y}.png"
    svc = Service(load_config(env={TILE_URL_ENV: url, "GCS_PDM_MAP_TILE_ATTRIBUTION": "local tiles"},
                              data_dir=str(tmp_path / "tiles"), api_token="console-test-token-0123456789"))
    try:
        s = TestClient(create_app(svc)).get("/console/settings").json()
        assert (s["tile_url"], s["tile_attribution"]) == (url, "local tiles")
    finally:
        svc.close()


def test_the_service_keeps_the_track_for_a_reloaded_page(client):
    """GET /status/track: positions at 1 Hz of message time (faster ones decimated), invalid ones
    skipped and counted, only the window's worth kept."""
    from gcs_pdm.frames import PositionFrame

    state = client.app.state.service.state
    assert client.get("/status/track").json()["points"] == []
    for k in range(50):  # 10 Hz for 5 s
        t = 100.0 + 0.1 * k
        state.apply_frame(PositionFrame(t, 52.0 + 1e-5 * k, 4.0, 30.0 + k, 10.0, 0.0, 0.0, 0.0))
    state.apply_frame(PositionFrame(106.0, None, None, None, None, None, None, None))
    state.apply_frame(PositionFrame(107.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))  # no GPS fix
    body = client.get("/status/track").json()
    pts = body["points"]
    assert [p[0] for p in pts] == pytest.approx([100.0, 101.0, 102.0, 103.0, 104.0])
    assert body["fields"] == ["time_s", "lat_deg", "lon_deg", "alt_m", "relative_alt_m"]
    assert pts[1][1:] == pytest.approx([52.0 + 1e-4, 4.0, 40.0, 10.0])
    assert body["skipped_invalid"] == 2
    assert [p[0] for p in client.get("/status/track", params={"since_s": 102.0}).json()["points"]] == [103.0, 104.0]
    assert client.get("/status/track", params={"since_s": "nan"}).status_code == 422


def test_the_track_is_bounded_by_its_window_and_restarts_with_the_clock():
    from gcs_pdm.service.track import Track

    tr = Track(window_s=60.0, interval_s=1.0)
    for t in range(1000):
        tr.add(float(t), 52.0, 4.0, 30.0)
    times = [p[0] for p in tr.points()]
    assert times[0] == 939.0 and times[-1] == 999.0 and len(times) == 61
    assert tr.add(997.5, 52.0, 4.0) is False and len(tr.points()) == 61  # late by a little: decimated
    assert tr.add(10.0, 52.0, 4.0) is True  # the clock went back: a new session, a new track
    assert [p[0] for p in tr.points()] == [10.0] and tr.restarts == 1
    assert not tr.add(11.0, 91.0, 4.0) and not tr.add(12.0, float("nan"), 4.0) and tr.skipped_invalid == 2
    with pytest.raises(ValueError):
        Track(window_s=0.0)


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


def test_the_console_says_what_every_fault_kinds_magnitude_means():
    """app.js keeps its own copy of the fault vocabulary (a browser cannot import Python): every type
    the diagnoser can raise has a wording there, and its advisories are the diagnoser's (a model
    mismatch is told as a warning, not a red fault, and its statistic is not a 'power lost')."""
    from gcs_pdm.diagnosis.faults import ADVISORY_TYPES, FAULT_TYPES

    app = (REPO / "gcs_pdm" / "service" / "console" / "app.js").read_text()
    table = app[app.index("const FAULT_MAGNITUDE = {"):app.index("};", app.index("const FAULT_MAGNITUDE = {"))]
    assert set(re.findall(r"^\s+(\w+): \(m\) =>", table, re.M)) == set(FAULT_TYPES)
    advisory = re.search(r"const ADVISORY_FAULTS = new Set\(\[(.*?)\]\)", app).group(1)
    assert set(re.findall(r'"(\w+)"', advisory)) == set(ADVISORY_TYPES)
    assert table.count("power lost") == 1
