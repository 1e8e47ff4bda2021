"""Decisions that do not go stale (issue 31, part 4): a proposal's gate (age, blocked, stale), the
vehicle-level outlook line and its alarm (banner, STATUSTEXT, replan)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from gcs_pdm.models.powertrain import MotorFault
from gcs_pdm.service.decision import outlook_alarm, outlook_line, proposal_gate

sys.path.insert(0, str(Path(__file__).parent))


def test_gate_blocks_on_a_lost_link_a_failed_or_a_landed_vehicle():
    g = proposal_gate(100.0, 110.0, reevaluate_every_s=30.0, link_lost="no heartbeat for 5 s")
    assert g.blocked and "link lost" in g.reason and g.age_s == pytest.approx(10.0)
    g = proposal_gate(100.0, 110.0, reevaluate_every_s=30.0, failed="PDM: crashed")
    assert g.blocked and "failed" in g.reason
    g = proposal_gate(100.0, 110.0, reevaluate_every_s=30.0, flying=False, not_flying_reason="disarmed (HEARTBEAT)")
    assert g.blocked and "disarmed" in g.reason
    g = proposal_gate(100.0, 110.0, reevaluate_every_s=30.0)
    assert not g.blocked and not g.stale and g.reason is None


def test_gate_marks_an_old_proposal_or_changed_faults_stale():
    g = proposal_gate(100.0, 131.0, reevaluate_every_s=30.0)
    assert g.stale and not g.blocked and "31 s old" in g.reason
    planned = [{"motor": "aft", "magnitude": 0.7, "kind": "motor_power_loss"}]
    assert not proposal_gate(100.0, 101.0, reevaluate_every_s=30.0, plan_faults=planned,
                             faults_now=[MotorFault("aft", 0.72)]).stale  # refined, not changed
    g = proposal_gate(100.0, 101.0, reevaluate_every_s=30.0, plan_faults=planned,
                      faults_now=[MotorFault("aft", 0.7), MotorFault("fwd", 0.3)])
    assert g.stale and "faults changed" in g.reason
    assert proposal_gate(100.0, 101.0, reevaluate_every_s=30.0, plan_faults=planned,
                         faults_now=[MotorFault("aft", 0.9)]).stale


def test_outlook_alarm_and_line():
    ok = {"p_failure": 0.0, "landing_soc_p05": 0.2, "landing_soc_p50": 0.3, "landing_soc_p95": 0.4}
    assert outlook_alarm(ok, max_failure_probability=0.02, reserve_soc=0.15) is None
    assert outlook_line(ok) == "gets home with 30% (20%–40%), P(failure) 0.0%"  # draws not said: the value
    # no failing draw among 200 is a bound (1 - 0.05^(1/200) = 1.49 %), not "0 %"
    assert outlook_line(dict(ok, samples=200)) == "gets home with 30% (20%–40%), P(failure) < 1.5% (0 of 200 draws failed)"
    assert outlook_line(dict(ok, p_failure=0.035, samples=200)).endswith("P(failure) 3.5%")
    low = dict(ok, landing_soc_p05=0.1)
    a = outlook_alarm(low, max_failure_probability=0.02, reserve_soc=0.15)
    assert a["severity"] == "warning" and "reserve" in a["text"] and a["statustext"].startswith("PDM:")
    assert len(a["statustext"]) <= 50  # one STATUSTEXT
    risky = dict(ok, p_failure=0.05)
    a = outlook_alarm(risky, max_failure_probability=0.02, reserve_soc=0.15)
    assert a["level"] == "critical" and a.get("severity") != "warning" and len(a["statustext"]) <= 50
    assert outlook_alarm({"unknown": "no estimate"}, max_failure_probability=0.02, reserve_soc=0.15) is None
    assert outlook_line({"unknown": "no estimate"}) == "outlook unknown: no estimate"


@pytest.mark.slow
def test_the_outlook_of_an_unflyable_mission_raises_the_alarm_once_and_replans(tmp_path):
    """The original Table III order with the aft motor at 30 %: the current mission's outlook over the
    risk draws crosses the reserve; the service says it in /status (line and banner), sends a
    STATUSTEXT once, and replans."""
    from test_service_live_loop import fault_frames, make_loop, original_mission, run, statustexts

    from gcs_pdm.service.routers.health import status

    mission = original_mission()
    svc, loop, link, vehicle = make_loop(tmp_path, "advise", mission)
    try:
        run(loop, fault_frames(), mission)
        n_plans = len(svc.store.plans(limit=1000))
        snap = loop.snapshot()
        loop.executor.evaluate_outlook(snap)
        outlook = svc.state.get("outlook")
        assert "unknown" not in outlook, outlook
        assert outlook["route"] == [3, 4, 5, 6, 7, 8, 9, 10] and outlook["samples"] == 200
        assert outlook["line"].startswith("gets home with")
        assert outlook["alarm"] is not None and outlook["alarm"]["level"] == "critical"
        warnings = status(svc)["warnings"]
        assert any(w["kind"] == "landing_forecast" for w in warnings)
        texts = [t for t in statustexts(link) if t.startswith("PDM: P(fail)") or t.startswith("PDM: landing")]
        assert len(texts) == 1
        deadline = time.monotonic() + 60
        while len(svc.store.plans(limit=1000)) == n_plans and time.monotonic() < deadline:
            time.sleep(0.05)
        while loop.executor.busy and time.monotonic() < deadline:
            time.sleep(0.05)
        plans = svc.store.plans(limit=1000)
        assert len(plans) > n_plans and plans[0]["trigger"].startswith("alarm:")
        # said once per crossing: the next evaluation, still below, sends nothing new
        loop.executor.evaluate_outlook(loop.snapshot())
        assert len([t for t in statustexts(link) if t.startswith(("PDM: P(fail)", "PDM: landing"))]) == 1
    finally:
        svc.close()
