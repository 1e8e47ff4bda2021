"""Screenshots of the operator's console in its main states, for docs/console.md.

Runs ``gcs-pdm serve`` (advise policy) fed by ``gcs-pdm sim`` with the demo's motor fault on free
loopback ports, opens the console in the system's Chromium, and saves into docs/console/:
the proposal waiting for the operator, the confirmed upload, the stale link after the vehicle goes
silent, Swagger UI served offline, a finished fit job, and a vehicle flying outside the conditions
its active set was fitted on (the service restarted on a battery fit's set). About two minutes:

    python scripts/make_console_screenshots.py [--out docs/console] [--speedup 40]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "browser"))
sys.path.insert(0, str(REPO))

from console_harness import RequestLog, Service, Sim, battery_fit_request, launch, motor_fit_request  # noqa: E402


def approve_until_uploaded(page, token: str, timeout_s: float = 180.0) -> None:
    """Approve as an operator does until an upload is confirmed: a proposal older than the service's
    re-evaluation period (or made under other faults) is re-planned when approved, and the new
    proposal shows instead of an upload; so each proposal the page shows is approved in turn, the
    token given when the page asks for it."""
    import time

    from playwright.sync_api import Error as PlaywrightError

    clicked: set[str] = set()
    deadline = time.monotonic() + timeout_s
    confirmed = page.locator('.outcome[data-upload-status="confirmed"]')
    while confirmed.count() == 0:
        if time.monotonic() > deadline:
            raise SystemExit(f"no confirmed upload within {timeout_s:.0f} s (approved plans {sorted(clicked)})")
        if page.locator("#token-dialog").is_visible():
            page.locator("#token-input").fill(token)
            page.locator("#token-save").click()
        for button in page.locator(".plan button.approve:enabled").all():
            plan_id = button.get_attribute("data-id")
            if plan_id not in clicked:
                try:
                    button.click(timeout=5_000)
                except PlaywrightError:  # the page re-rendered the plan away meanwhile: look again
                    break
                clicked.add(plan_id)
                break
        page.wait_for_timeout(250)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO / "docs" / "console"))
    ap.add_argument("--speedup", type=float, default=40.0)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from playwright.sync_api import expect, sync_playwright

    shots: list[str] = []
    with tempfile.TemporaryDirectory(prefix="gcs-pdm-shots-") as tmp, sync_playwright() as p:
        # the demo's re-evaluation period at this speed-up: the outlook is evaluated while the
        # vehicle flies (30 s x the speed-up left it "not evaluated yet" in every shot); a proposal
        # gone stale meanwhile is re-planned when approved, which approve_until_uploaded follows
        from gcs_pdm.service.demo import reevaluate_every_s

        service = Service(Path(tmp) / "svc",
                          extra_env={"GCS_PDM_REEVALUATE_EVERY_S": f"{reevaluate_every_s(args.speedup):g}"}).start()
        sim = Sim(service, speedup=args.speedup).start()
        browser = launch(p)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            requests = RequestLog(page)

            def shot(name: str, full_page: bool = True) -> None:
                path = out / name
                page.screenshot(path=str(path), full_page=full_page)
                shots.append(str(path.relative_to(REPO) if path.is_relative_to(REPO) else path))

            page.goto(service.url + "/")
            expect(page.locator("#map path.proposed-route")).to_have_count(1, timeout=300_000)  # a busy machine
            page.wait_for_timeout(2500)  # let the track and the plots gather a few more points
            shot("1_fault_and_proposal.png")
            approve_until_uploaded(page, service.token)
            page.wait_for_timeout(4000)
            shot("2_upload_confirmed.png")
            sim.stop()
            expect(page.locator('[data-banner="stale"], [data-banner="link-lost"]')).to_have_count(1, timeout=60_000)
            shot("3_link_stale.png")
            page.goto(service.url + "/docs")
            expect(page.locator(".swagger-ui .info .title")).to_contain_text("gcs-pdm", timeout=20_000)
            shot("4_api_docs_offline.png", full_page=False)
            job = service.send("POST", "/jobs/fit", motor_fit_request("motor_from_learn_01"))["id"]
            page.goto(service.url + "/")
            expect(page.locator(f'[data-job="{job}"]')).to_have_attribute("data-status", "succeeded", timeout=120_000)
            page.wait_for_timeout(1000)
            path = out / "5_fit_job.png"
            page.locator("#fits-panel").screenshot(path=str(path))
            shots.append(str(path.relative_to(REPO) if path.is_relative_to(REPO) else path))
            # a battery fit's set (its one training flight in 6-8 °C air), the service restarted on it
            job = service.send("POST", "/jobs/fit", battery_fit_request("cold_battery"))["id"]
            expect(page.locator(f'[data-job="{job}"]')).to_have_attribute("data-status", "succeeded", timeout=120_000)
            service.send("POST", "/parameter-sets/cold_battery/activate", {})
            service.stop()
            service.start()
            sim = Sim(service, speedup=args.speedup).start()
            page.goto(service.url + "/")
            expect(page.locator('[data-banner="status-outside_fit_envelope"]')).to_have_count(1, timeout=60_000)
            # the restarted service's first re-evaluation (one period of the vehicle's time)
            expect(page.locator("#outlook")).not_to_contain_text("not evaluated yet", timeout=120_000)
            page.wait_for_timeout(3000)
            shot("6_outside_fit_envelope.png", full_page=False)
            foreign = requests.foreign(service.host)
            if foreign:
                raise SystemExit(f"the console asked other hosts: {foreign}")
        finally:
            browser.close()
            sim.stop()
            service.stop()
    print(json.dumps({"screenshots": shots}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
