"""The operator's console in a real Chromium, against ``gcs-pdm serve`` fed by ``gcs-pdm sim``.

A motor fault under the ``advise`` policy: the fault banner appears, the proposed route is drawn
on the map, Approve (with the token typed into the page) uploads it and the page shows it
confirmed; when the vehicle stops sending, a stale/link-lost banner appears within seconds. The
page, and Swagger UI at /docs, ask nothing of any host but the service.
"""
from __future__ import annotations

import re
import time

import pytest
from playwright.sync_api import expect, sync_playwright

from gcs_pdm.service.console_routes import TILE_URL_ENV
from console_harness import RequestLog, Service, Sim, battery_fit_request, launch, motor_fit_request

pytestmark = pytest.mark.slow


def service_time_settled(service, quiet_s: float = 1.0, limit_s: float = 60.0) -> float:
    """Wall time (monotonic) at which the service's message time last advanced."""
    start = time.monotonic()
    last, changed = service.get("/status")["time_s"], start
    while time.monotonic() - changed < quiet_s:
        assert time.monotonic() - start < limit_s, "the service's message time kept advancing without the vehicle"
        time.sleep(0.1)
        now = service.get("/status")["time_s"]
        if now != last:
            last, changed = now, time.monotonic()
    return changed


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        b = launch(p)
        yield b
        b.close()


@pytest.fixture
def page(browser):
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    pg = ctx.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    yield pg
    ctx.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


@pytest.fixture
def service(tmp_path):
    # the sim flies at 40x: a proposal re-evaluated every 30 s of message time would be stale before
    # the page can approve it (test_console_alarm.py and test_service_live_loop.py cover staleness)
    svc = Service(tmp_path / "svc", extra_env={"GCS_PDM_REEVALUATE_EVERY_S": "3600"}).start()
    yield svc
    svc.stop()


@pytest.mark.timeout(180)
def test_fault_proposal_approve_confirmed_then_link_loss(service, page):
    sim = Sim(service).start()
    try:
        requests = RequestLog(page)
        page.goto(service.url + "/")
        expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=15_000)
        # the mission is drawn in the local frame (no tiles configured), home marked
        # (once the service has downloaded the vehicle's mission: on a loaded machine that can take a while)
        expect(page.locator("#map path.current-route")).to_have_count(1, timeout=60_000)
        expect(page.locator("#map-legend")).to_contain_text("local frame")
        # one card per pack and per motor the service reports, with numbers once telemetry flows
        status = service.get("/status")
        expect(page.locator("#packs .card")).to_have_count(len(status["packs"]))
        expect(page.locator("#motors .card")).to_have_count(len(status["motors"]))
        # each pack card says whether the pack behaves like its model (not judged until its window fills)
        expect(page.locator("#packs .card .row.model")).to_have_count(len(status["packs"]))
        expect(page.locator("#packs .card .row.model").first).to_contain_text(
            re.compile("not judged yet|matches|does not match its model"), timeout=30_000)

        # the diagnoser's fault becomes a banner
        fault_banner = page.locator('[data-banner^="fault-"]')
        expect(fault_banner).to_have_count(1, timeout=90_000)
        expect(fault_banner).to_contain_text("motor power loss on aft")
        # the proposal is drawn over the current mission, and compared with it
        expect(page.locator("#map path.proposed-route")).to_have_count(1, timeout=60_000)
        # the fault's proposal (an earlier one may answer the landing-forecast alarm: issue 31)
        deadline = time.monotonic() + 60
        proposed = []
        while not proposed and time.monotonic() < deadline:
            proposed = [p for p in service.get("/missions/proposed") if p["trigger"].startswith("fault:")]
            time.sleep(0.2)
        assert proposed, "the service proposed nothing on the fault"
        plan = proposed[0]
        dropped = set(plan["previous_route"]) - set(plan["chosen"]["route"])
        expect(page.locator("#map .wp-label.dropped")).to_have_count(len(dropped))
        expect(page.locator("#map .wp-label.proposed")).to_have_count(len(plan["chosen"]["route"]))
        card = page.locator(f'[data-plan="{plan["id"]}"]')
        expect(card).to_contain_text("landing SoC")
        expect(card).to_contain_text(f'{plan["chosen"]["reward"]:.1f}')
        expect(card).to_contain_text("probability of failure")
        # the Monte Carlo probability of the proposal (issue 16), as stored with the plan
        pf = plan["chosen"]["failure_probability"]
        expect(card.locator("[data-pfail]").filter(has_text=f"{100 * pf:.0f} %")).not_to_have_count(0)
        # the motor card shows the lost health
        expect(page.locator('[data-motor="aft"] h3')).to_contain_text("health 3")

        # Approve: the page asks for the token once, then the upload is confirmed by read-back
        page.locator(f"#approve-{plan['id']}").click()
        expect(page.locator("#token-dialog")).to_be_visible()
        page.locator("#token-input").fill(service.token)
        page.locator("#token-save").click()
        expect(page.locator(f'.outcome[data-upload-status="confirmed"]')).to_contain_text(
            f"Plan {plan['id']}", timeout=45_000)
        assert any(u["plan_id"] == plan["id"] and u["status"] == "confirmed" for u in service.get("/missions/uploads"))
        expect(page.locator("#timeline")).to_contain_text(f"Upload of plan {plan['id']}: confirmed")
        assert page.evaluate("sessionStorage.getItem('gcs-pdm-token')") == service.token

        # the vehicle goes silent: a banner says so within seconds
        expect(page.locator('[data-banner="stale"], [data-banner="link-lost"]')).to_have_count(0)
        sim.stop()
        # The service may still be working through datagrams that arrived before the stop (on a
        # busy machine); the page can only know once the vehicle's message time stops advancing.
        t_last = service_time_settled(service)
        expect(page.locator('[data-banner="stale"], [data-banner="link-lost"]')).to_have_count(1, timeout=20_000)
        took = time.monotonic() - t_last
        assert took < 12.0, took
        expect(page.locator("#conn")).not_to_have_attribute("data-state", "live")
        # once the service declares the link lost, its event reads as a loss and no pack claims
        # "no cut-off predicted" from a countdown the service has cleared
        expect(page.locator('[data-banner="link-lost"]')).to_have_count(1, timeout=20_000)
        expect(page.locator("#timeline")).to_contain_text("Link lost", timeout=10_000)
        expect(page.locator("#packs")).not_to_contain_text("no cut-off predicted", timeout=10_000)

        # a reload keeps the track: the vehicle no longer moves, so the page alone would have one
        # point, not a line; the line is the service's track (GET /status/track)
        assert len(service.get("/status/track")["points"]) > 1
        page.reload()
        expect(page.locator("#map path.track")).to_have_count(1, timeout=10_000)

        assert requests.urls and not requests.foreign(service.host), requests.foreign(service.host)
    finally:
        sim.stop()


@pytest.mark.timeout(120)
def test_swagger_ui_offline_and_reconnect_after_restart(service, page, tmp_path):
    requests = RequestLog(page)
    page.goto(service.url + "/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("gcs-pdm", timeout=20_000)
    expect(page.locator(".swagger-ui .opblock-summary-path").first).to_be_visible()
    assert not requests.foreign(service.host), requests.foreign(service.host)

    page.goto(service.url + "/")
    expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=15_000)
    expect(page.locator('[data-banner="no-telemetry"]')).to_contain_text("No telemetry yet")
    first = page.evaluate("S.instance")
    service.stop()
    expect(page.locator('[data-banner="service"]')).to_have_count(1, timeout=10_000)
    expect(page.locator("#conn")).to_have_attribute("data-state", "down")
    # the restarted service has a tile server configured (its own host here: the test has no other)
    tiles = f"{service.url}/console/vendor/leaflet/images/layers.png?z={{z}}&x={{x}}&y={{y}}"
    again = Service(tmp_path / "svc2", http_port=service.http_port, extra_env={TILE_URL_ENV: tiles}).start()
    try:
        expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=20_000)
        expect(page.locator('[data-banner="service"]')).to_have_count(0)
        assert page.evaluate("S.instance") not in (None, first)
        # the new service's events reach the page (its numbering began again)
        again.send("PUT", "/policy", {"policy": "auto"})
        expect(page.locator("#timeline")).to_contain_text("Policy set to auto", timeout=10_000)
        # with a tile URL the map draws over tiles instead of the local frame
        expect(page.locator("#map-legend")).to_contain_text("map tiles", timeout=10_000)
        expect(page.locator("#map img.leaflet-tile-loaded").first).to_be_visible(timeout=10_000)
        assert any("layers.png?z=" in u for u in requests.urls)
    finally:
        again.stop()
    assert not requests.foreign(service.host), requests.foreign(service.host)


@pytest.mark.timeout(150)
def test_fit_jobs_progress_results_cancel_and_activate(service, page):
    requests = RequestLog(page)
    page.goto(service.url + "/")
    expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=15_000)
    done = service.send("POST", "/jobs/fit", motor_fit_request("console_motor"))["id"]
    job = page.locator(f'[data-job="{done}"]')
    expect(job).to_have_attribute("data-status", "succeeded", timeout=90_000)
    expect(job).to_contain_text("saved as console_motor")
    expect(job.locator("table.compare")).to_contain_text("RMSE learned")
    plot = job.locator("img").first
    expect(plot).to_be_visible()
    assert page.evaluate("(img) => img.naturalWidth", plot.element_handle()) > 100
    # progress ticks never reach the timeline, even with jobs shown
    page.locator('#filters input[value="jobs"]').check()
    expect(page.locator("#timeline")).to_contain_text("succeeded")
    ticks = [e for e in service.get("/events/poll?since=0") if e["kind"] == "job" and e["data"].get("progress", 0) > 0]
    assert ticks, "the fit reported no progress"
    shown = page.locator('#timeline li[data-kind="job"]').count()
    assert shown < len(ticks) + 3 and shown <= 4, (shown, len(ticks))

    # cancel a long one from the page (the token is asked once)
    # long enough on a fast host too (40 starts finished before the click on one): the cancel, not
    # the fit's end, must decide the status
    slow = service.send("POST", "/jobs/fit", motor_fit_request("console_slow", starts=2000))["id"]
    cancel = page.locator(f'[data-job="{slow}"] button[data-cancel]')
    expect(cancel).to_be_visible(timeout=20_000)
    cancel.click()
    page.locator("#token-input").fill(service.token)
    page.locator("#token-save").click()
    expect(page.locator(f'[data-job="{slow}"]')).to_have_attribute("data-status", "cancelled", timeout=60_000)

    # activate the fitted set
    page.locator('#paramsets button[data-activate="console_motor"]').click()
    expect(page.locator('#paramsets [data-set="console_motor"]')).to_contain_text("active", timeout=10_000)
    assert next(p for p in service.get("/parameter-sets") if p["name"] == "console_motor")["active"]
    assert not requests.foreign(service.host), requests.foreign(service.host)


@pytest.mark.timeout(120)
def test_a_battery_fit_job_shows_what_its_fit_extrapolates(service, page):
    page.goto(service.url + "/")
    expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=15_000)
    done = service.send("POST", "/jobs/fit", battery_fit_request("console_battery"))["id"]
    job = page.locator(f'[data-job="{done}"]')
    expect(job).to_have_attribute("data-status", "succeeded", timeout=90_000)
    warnings = job.locator("ul.fit-warnings li")
    stored = service.get(f"/jobs/{done}/result")["fits"]["LLF20"]["warnings"]
    assert any("initial SoC extrapolated" in w for w in stored) and any("outside the training conditions" in w for w in stored)
    expect(warnings).to_have_count(len(stored))
    expect(warnings.filter(has_text="LLF20: test flight chen2020_11: initial SoC extrapolated")).to_have_count(1)
    expect(warnings.filter(has_text="LLF20: test flight chen2020_11: outside the training conditions")).to_have_count(1)


@pytest.mark.timeout(150)
def test_flying_outside_the_conditions_a_set_was_fitted_on_is_a_banner(service, page):
    """The set a battery fit saved (its one training flight in 6-8 °C air) activated and the service
    restarted on it (the filters fly the values they started with), the simulated vehicle flying in
    warmer air: the console says its predictions extrapolate (docs/service.md, "Fit envelope"), from
    the training envelope the set carries."""
    done = service.send("POST", "/jobs/fit", battery_fit_request("cold_battery"))["id"]
    deadline = time.monotonic() + 90
    while service.get(f"/jobs/{done}")["status"] != "succeeded":
        assert time.monotonic() < deadline, service.get(f"/jobs/{done}")
        time.sleep(0.5)
    stored = next(p for p in service.get("/parameter-sets") if p["name"] == "cold_battery")
    training = stored["provenance"]["packs"]["LLF20"]["training_envelope"]
    assert training["ambient_c"][1] < 10.0
    service.send("POST", "/parameter-sets/cold_battery/activate", {})
    service.stop()
    service.start()
    sim = Sim(service).start()
    try:
        page.goto(service.url + "/")
        expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=15_000)
        banner = page.locator('[data-banner="status-outside_fit_envelope"]')
        expect(banner).to_have_count(1, timeout=30_000)
        expect(banner).to_contain_text("Outside the conditions the model was fitted on: LLF20")
        expect(banner).to_contain_text("predictions extrapolate")
        # on the pack's own card, and only there: the other packs kept the paper's values
        row = page.locator('#packs [data-pack="LLF20"] .row.envelope')
        expect(row).to_contain_text("fitted conditions")
        expect(row).to_contain_text("outside: air temperature reaches")
        expect(page.locator("#packs .row.envelope")).to_have_count(1)
        # this vehicle's LLF20 is not the fitted cell: the model check says so, as an advisory (a
        # warning with its statistic, not a red fault with a "power lost")
        advisory = page.locator('[data-banner^="fault-"]', has_text="model mismatch on LLF20")
        expect(advisory).to_have_count(1, timeout=60_000)
        expect(advisory).to_have_class(re.compile(r"\bwarning\b"))
        expect(advisory).to_contain_text("Advisory: model mismatch on LLF20")
        expect(advisory).to_contain_text("statistic")
        expect(advisory).not_to_contain_text("power lost")
        status = service.get("/status")
        assert status["fit_envelope"]["outside"] == ["LLF20"]
        assert set(status["fit_envelope"]["packs"]) == {"LLF20"}   # the packs the fit did not learn: not judged
    finally:
        sim.stop()


@pytest.mark.timeout(120)
def test_a_second_sender_on_the_vehicles_id_is_a_banner(service, page):
    """A second sender using the vehicle's own system and component id (another vehicle or simulator
    left on the same id): its readings cannot be told apart by the ids, so the console says so, from
    the interleaved MAVLink sequence numbers (docs/operations.md, "One sender per id")."""
    import socket
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "mavlink"))
    from mavlink_builders import PacketFactory

    sim = Sim(service).start()
    try:
        page.goto(service.url + "/")
        expect(page.locator("#conn")).to_have_attribute("data-state", "live", timeout=15_000)
        expect(page.locator("#packs .card").first).to_contain_text("V", timeout=30_000)
        expect(page.locator('[data-banner="status-shared_vehicle_id"]')).to_have_count(0)
        # the link is not signed: the console says so (issue 34), as a warning, not a critical banner
        unsigned = page.locator('[data-banner="status-unsigned_link"]')
        expect(unsigned).to_have_count(1, timeout=15_000)
        expect(unsigned).to_contain_text("MAVLink link not signed")
        other = PacketFactory(1, 1, numbered=True)
        other.mav.seq = 131
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for k in range(400):
                sock.sendto(other.battery(0, [4000] * 5, 1500, 3000), ("127.0.0.1", service.udp_port))
                time.sleep(0.01)
        finally:
            sock.close()
        banner = page.locator('[data-banner="status-shared_vehicle_id"]')
        expect(banner).to_have_count(1, timeout=15_000)
        expect(banner).to_contain_text("More than one sender on the vehicle's id")
        expect(banner).to_contain_text("system 1 component 1")
    finally:
        sim.stop()
