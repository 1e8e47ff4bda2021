"""The console's words and numbers, in a real Chromium (issue 33): each fault kind's magnitude in
its own words in the timeline (a model mismatch is no "power lost"), and one waypoint numbering
on the map and in the plan's table, for the current mission (before any plan) and a proposal.

The page runs against a real ``gcs-pdm serve`` with no vehicle; the mission, the proposal and the
event stream are answered by the test (``page.route``), so the page's own code is what is checked.
"""
from __future__ import annotations

import json

import pytest
from playwright.sync_api import expect, sync_playwright

from console_harness import Service, launch

pytestmark = pytest.mark.slow

HOME = (47.3977419, 8.5455938)


def _item(seq: int, command: int, north_m: float = 0.0, east_m: float = 0.0, z: float = 100.0) -> dict:
    lat = HOME[0] + north_m / 111_195.0
    lon = HOME[1] + east_m / (111_195.0 * 0.6768)
    return {"seq": seq, "frame": 3 if seq else 0, "command": command, "current": int(seq == 1), "autocontinue": 1,
            "param1": 0.0, "param2": 0.0, "param3": 0.0, "param4": 0.0, "x": round(lat * 1e7), "y": round(lon * 1e7),
            "z": z, "mission_type": 0}


# home, takeoff, the objectives' waypoints 5, 7 and 9 (items 2..4), land: numbered by the service
MISSION = {"source": "download", "time_s": 12.0, "waypoints": {"2": 5, "3": 7, "4": 9},
           "items": [_item(0, 16), _item(1, 22), _item(2, 16, 400, 0), _item(3, 16, 400, 400), _item(4, 16, 0, 400),
                     _item(5, 21)]}
# the proposal flies 9 then 5 and drops 7; its items are numbered by place, not by flight order
PLAN = {"id": 3, "time_s": 300.0, "trigger": "fault", "status": "proposed", "created_at": 1.0, "updated_at": 1.0,
        "previous_route": [5, 7, 9], "why": "",
        "items": [_item(0, 16), _item(1, 16, 0, 400), _item(2, 16, 400, 0), _item(3, 21)],
        "chosen": {"name": "planner", "route": [9, 5], "reward": 30.0, "feasible": True},
        "candidates": [{"name": "keep", "route": [5, 7, 9], "reward": 45.0, "feasible": False, "cause": "cut-off"},
                       {"name": "planner", "route": [9, 5], "reward": 30.0, "feasible": True}]}
EVENTS = [
    {"seq": 1, "kind": "fault", "wall_time": 1.0,
     "data": {"time_s": 250.0, "kind": "model_mismatch", "target": "LLF20", "magnitude": 1.93, "source": "diagnoser"}},
    {"seq": 2, "kind": "fault", "wall_time": 2.0,
     "data": {"time_s": 290.0, "kind": "motor_power_loss", "target": "aft", "magnitude": 0.7, "source": "diagnoser"}},
    {"seq": 3, "kind": "fault", "wall_time": 3.0,
     "data": {"time_s": 295.0, "kind": "pack_capacity_loss", "target": "ULA20", "magnitude": 0.2, "source": "diagnoser"}},
]


def _sse(events) -> str:
    return "".join(f"id: {e['seq']}\nevent: {e['kind']}\ndata: {json.dumps(e)}\n\n" for e in events)


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    svc = Service(tmp_path_factory.mktemp("svc")).start()
    yield svc
    svc.stop()


@pytest.mark.timeout(120)
def test_timeline_words_each_fault_kind_and_one_waypoint_numbering(service):
    with sync_playwright() as p:
        browser = launch(p)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            proposed: list[dict] = []  # none until the test proposes
            page.route("**/missions/current", lambda r: r.fulfill(json=MISSION))
            page.route("**/missions/proposed", lambda r: r.fulfill(json=proposed))
            page.route("**/events?*", lambda r: r.fulfill(status=200, content_type="text/event-stream",
                                                          body=_sse(EVENTS if proposed else EVENTS[:1])))
            page.goto(service.url + "/")

            # the current mission, before any plan: every waypoint carries the service's number
            labels = page.locator("#map .wp-label:not(.home):not(.proposed):not(.dropped)")
            expect(labels).to_have_count(3, timeout=20_000)
            assert sorted(labels.all_inner_texts()) == ["5", "7", "9"]

            # a model mismatch is worded as one, not as a power loss
            timeline = page.locator("#timeline")
            expect(timeline).to_contain_text("Fault: model mismatch on LLF20, statistic 1.93", timeout=15_000)

            # a proposal: its map labels are the waypoint numbers the plan's table shows
            proposed.append(PLAN)
            page.evaluate("connectEvents()")  # the stream again: the motor fault and the proposal
            expect(timeline).to_contain_text("Fault: motor power loss on aft, 70 % power lost", timeout=15_000)
            expect(timeline).to_contain_text("Fault: pack capacity loss on ULA20, 20 % capacity lost")
            page.evaluate("refreshPlans()")
            marks = page.locator("#map .wp-label.proposed")
            expect(marks).to_have_count(2, timeout=10_000)
            assert sorted(marks.all_inner_texts()) == ["5", "9"]
            expect(page.locator("#map .wp-label.dropped")).to_have_count(1)
            expect(page.locator('[data-plan="3"]')).to_contain_text("9 → 5")
            for line in timeline.locator("li").all_inner_texts():
                if "power lost" in line:
                    assert "motor power loss" in line, line
            assert not errors, errors
        finally:
            browser.close()
