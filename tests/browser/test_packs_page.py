"""The console's pack page in Chromium: a service whose database holds one pack's flights (synthetic
tlogs ingested), served by uvicorn in this process; the page lists the pack, plots its capacity and
resistance against cycles with the fit, the threshold and the forecast, and assigns a slot."""
from __future__ import annotations

import threading
import time

import pytest
from playwright.sync_api import expect, sync_playwright

from console_harness import free_port, launch

TOKEN = "packs-page-token-0123456789abcdef"


@pytest.fixture
def served(tmp_path):
    import uvicorn

    from gcs_pdm.packs.ingest import IngestSettings, run_ingest
    from gcs_pdm.packs.synthetic import SyntheticPack, write_pack_tlog
    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service

    logs = tmp_path / "logs"
    logs.mkdir()
    for k in range(6):
        write_pack_tlog(logs / f"f{k}.tlog", SyntheticPack(serial="PK-9", capacity_ah=5.0 * (1 - 0.03 * k),
                                                           resistance_ohm=0.02 * (1 + 0.06 * k)),
                        epoch_s=1.7e9 + 86400 * k, seed=k, bulk=False)
    svc = Service(load_config(env={}, data_dir=str(tmp_path / "data"), api_token=TOKEN))
    run_ingest(sorted(logs.glob("*.tlog")), IngestSettings(), workers=1, known=svc.packs.known_log,
               on_result=svc.packs.add_log_result)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(svc), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}", svc
    server.should_exit = True
    thread.join(10)
    svc.close()


@pytest.mark.slow
def test_the_pack_page_plots_the_trend_and_assigns_a_slot(served):
    url, svc = served
    with sync_playwright() as p:
        browser = launch(p)
        page = browser.new_page(viewport={"width": 1300, "height": 1000})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url + "/console/packs.html")
        row = page.locator("tr.pack-row")
        expect(row).to_have_count(1)
        expect(row).to_contain_text("PK-9")
        expect(row).to_contain_text("autopilot serial")
        expect(page.locator("#pack-title")).to_contain_text("PK-9: 6 flight(s)")
        expect(page.locator("#plot-capacity circle.point")).to_have_count(6)
        expect(page.locator("#plot-resistance circle.point")).to_have_count(6)
        expect(page.locator("#plot-capacity path.fit")).to_have_count(1)
        expect(page.locator("#plot-capacity line.threshold")).to_have_count(1)
        expect(page.locator("#forecast")).to_contain_text("80% capacity at")
        page.once("dialog", lambda d: d.accept(TOKEN))
        page.fill("#assign-slot", "battery1")
        page.fill("#assign-pack", "P-21")
        page.click("#assign-form button")
        expect(page.locator("#assign-message")).to_have_text("slot battery1: pack P-21")
        expect(page.locator("#assignments")).to_contain_text("battery1: P-21")
        browser.close()
    assert svc.packs.assignments()["battery1"]["pack_id"] == "P-21"
    assert not errors, errors
