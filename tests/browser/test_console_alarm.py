"""The landing-forecast alarm in a real Chromium (issue 31, part 4): ``gcs-pdm serve`` fed by
``gcs-pdm sim`` flying the Table III mission with the demo's motor fault. The vehicle-level line
("gets home with …") is always on the page; once the current mission's forecast crosses the reserve
(or P(failure) rises above ε) a red banner appears, the line is marked, the ground station is told
(STATUSTEXT) and a replan proposes a route."""
from __future__ import annotations

import re
import time

import pytest
from playwright.sync_api import expect, sync_playwright

from console_harness import Service, Sim, launch

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        b = launch(p)
        yield b
        b.close()


@pytest.mark.timeout(240)
def test_the_landing_forecast_alarm_is_a_banner_and_a_marked_outlook_line(tmp_path, browser):
    # the sim flies at 40x: re-evaluate every 120 s of message time (3 s of wall time)
    service = Service(tmp_path / "svc", extra_env={"GCS_PDM_REEVALUATE_EVERY_S": "120"}).start()
    sim = Sim(service).start()
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = ctx.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(service.url + "/")
        outlook = page.locator("#outlook")
        expect(outlook).to_have_count(1, timeout=15_000)
        expect(outlook).to_contain_text("outlook unknown")  # said, before the first evaluation
        expect(outlook).to_contain_text("gets home with", timeout=90_000)
        expect(page.locator('[data-banner="status-landing_forecast"]')).to_have_count(1, timeout=150_000)
        expect(outlook).to_have_attribute("data-alarm", "critical")
        status = service.get("/status")
        assert status["outlook"]["alarm"]["kind"] == "landing_forecast"
        assert any(w["kind"] == "landing_forecast" for w in status["warnings"])
        # and a replan (recorded once its planner has run)
        deadline = time.monotonic() + 60
        trigger: list[str] = []
        while time.monotonic() < deadline and not any(t.startswith("alarm:") for t in trigger):
            time.sleep(0.5)
            trigger = [p["trigger"] for p in service.get("/missions/history?limit=50")]
        assert any(t.startswith("alarm:") for t in trigger), (trigger, (tmp_path / "svc" / "serve.log").read_text()[-3000:])
        # a waiting proposal shows its age; once the vehicle is silent, Approve and Reject are off with the reason
        expect(page.locator(".plan .gate").first).to_contain_text("s old", timeout=60_000)
        approve = page.locator(".plan button.approve").first
        expect(approve).to_be_enabled()
        sim.stop()
        expect(approve).to_be_disabled(timeout=30_000)
        expect(approve).to_have_attribute("title", re.compile("link lost"))
        expect(page.locator(".plan button.reject").first).to_be_disabled()
        expect(page.locator(".plan .gate").first).to_contain_text("link lost")
        assert not errors, f"JavaScript errors on the page: {errors}"
    finally:
        ctx.close()
        sim.stop()
        service.stop()
