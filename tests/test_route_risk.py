"""A route's Monte Carlo risk (``adapters.route_risk``): one batched prediction with per-sample
outcomes, for the paper's aircraft (the same numbers as the per-sample loop it replaced, within the
sampling tolerance) and for any vehicle description (its packs, motors, faults and limits)."""
from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
from gcs_pdm.estimation.synthetic import fly_synthetic
from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.models import kernel
from gcs_pdm.models.powertrain import DescribedMotorFault, MotorFault
from gcs_pdm.planning.simulator import VehicleSimulator, original_order
from gcs_pdm.planning.table3_scenario import preflight_scenario
from gcs_pdm.service import adapters
from gcs_pdm.service.decision import Candidate
from gcs_pdm.sim.truth import true_parameters
from gcs_pdm.vehicle.presets import PRESETS

sys.path.insert(0, str(Path(__file__).parent))
from test_planning_vehicle import _scenario as _pentagon  # noqa: E402  (five goals around the start)
from test_service_vehicle import _loop  # noqa: E402

REFERENCE = Path(__file__).parent / "reference" / "route_risk_per_sample_loop.json"

#: sampling tolerance of old vs new (different draws of one distribution, 3 seeds × 100 samples each):
#: the failure probability's sd of a difference of two such means is <= 0.041, the bound is ~3 sd
P_TOLERANCE = 0.12
#: landing SoC quantiles (mean over the seeds), absolute
SOC_TOLERANCE = 0.02


def _paper_estimator(initial_soc: float) -> StateEstimator:
    est = StateEstimator(true_parameters())
    for fr in fly_synthetic(true_parameters(), np.random.default_rng(2), duration_s=150.0,
                            initial_soc=initial_soc).frames:
        est.consume(fr)
    assert est.ready()
    return est


def test_the_batched_call_gives_the_per_sample_loops_numbers_on_the_paper_aircraft():
    """Recorded before the rewrite (tests/reference/route_risk_per_sample_loop.json): 100 one-sample
    calls from one rng. The batched call draws the same distribution in another order, so each
    case is compared as the mean over its three seeds within the sampling tolerance, and a verdict
    that was certain (p = 0 or 1 for every seed) must stay exactly that."""
    ref = json.loads(REFERENCE.read_text())
    sim = VehicleSimulator.for_scenario(preflight_scenario(10), true_parameters())
    full = original_order(sim.scenario)
    loads = {"full": adapters.route_load(sim, full), "half": adapters.route_load(sim, full[:5]),
             "two": adapters.route_load(sim, full[:2])}
    estimators = {s: _paper_estimator(s) for s in sorted({r["initial_soc"] for r in ref["results"]})}
    cases: dict = {}
    for r in ref["results"]:
        new = adapters.route_risk(estimators[r["initial_soc"]], loads[r["route"]],
                                  [MotorFault(m, x) for m, x in r["faults"]], seed=r["seed"])
        assert new["n_samples"] == 100 and new["seed"] == r["seed"]
        assert new["landing_samples"] == round(100 * (1 - new["failure_probability"]))
        assert set(new["landing_soc_packs"]) == {"LLF20", "ULA20", "LRF40", "URA40"}
        assert sum(new["failure_causes"].values()) == 100 - new["landing_samples"]
        cases.setdefault((r["initial_soc"], r["route"], bool(r["faults"])), []).append((r["risk"], new))
    mid = 0
    for key, pairs in cases.items():
        old_p = [o["failure_probability"] for o, _ in pairs]
        new_p = [n["failure_probability"] for _, n in pairs]
        if set(old_p) <= {0.0} or set(old_p) <= {1.0}:
            assert new_p == old_p, key
        else:
            mid += 1
            assert abs(np.mean(new_p) - np.mean(old_p)) <= P_TOLERANCE, (key, old_p, new_p)
        if all(o["landing_soc"]["p50"] is not None for o, _ in pairs):
            for k in ("p05", "p50", "p95"):
                old_q = np.mean([o["landing_soc"][k] for o, _ in pairs])
                new_q = np.mean([n["landing_soc"][k] for _, n in pairs])
                assert new_q == pytest.approx(old_q, abs=SOC_TOLERANCE), (key, k)
        else:
            assert all(n["landing_soc"]["p50"] is None for _, n in pairs), key
    assert mid >= 2  # the comparison covers uncertain outcomes, not only certain ones


def test_per_sample_outputs_agree_with_the_quantiles():
    est = _paper_estimator(1.0)
    load = FutureLoad.constant(800.0, 2000.0, 5.0)
    p = predict_from_estimator(est, load, rng=np.random.default_rng(5), n_samples=64, trajectories=False,
                               per_sample=True)
    failed = np.isfinite(p.sample_failure_time_s)
    assert 0 < failed.sum() < 64  # some of each, so both branches are checked
    assert p.p_failure == failed.mean()
    assert np.all((p.sample_failure_cause != kernel.FAIL_NONE) == failed)
    causes = {}
    for c in p.sample_failure_cause[failed]:
        causes[kernel.FAILURE_NAMES[int(c)]] = causes.get(kernel.FAILURE_NAMES[int(c)], 0) + 1
    assert causes == p.failure_causes
    assert np.quantile(p.sample_failure_time_s, (0.05, 0.5, 0.95), method="nearest") == pytest.approx(
        p.time_to_failure_s)
    assert p.sample_end_soc.shape == (64, 4)
    landed = p.sample_end_soc[~failed]
    assert np.all(np.isfinite(landed)) and np.all((landed > 0.0) & (landed < 1.0))
    # without the option the prediction carries no per-sample arrays
    q = predict_from_estimator(est, load, rng=np.random.default_rng(5), n_samples=8, trajectories=False)
    assert q.sample_failure_time_s is None and q.sample_end_soc is None


# --- any vehicle -----------------------------------------------------------------------------------

def _described_estimator(desc, voltage: float, current: float):
    est = adapters.make_estimator(desc)
    for t in range(3):
        est.consume(PackFrame(float(t), desc.pack_names[0], voltage, current, 25.0))
        for m in desc.motor_names:
            est.consume(MotorFrame(float(t), m, current / len(desc.motor_names), 5000.0, 30.0))
    assert est.ready()
    return est


@pytest.mark.parametrize("preset, voltage, current, airspeed", [("quad-4s", 16.0, 11.0, 8.0),
                                                                ("plane-3s", 12.2, 10.0, 20.0)])
def test_a_described_vehicles_risk_rises_with_the_route_and_a_believed_fault(preset, voltage, current, airspeed):
    desc = PRESETS[preset]
    est = _described_estimator(desc, voltage, current)
    sim = VehicleSimulator(_pentagon(1800.0, airspeed), vehicle=desc, state=est.powertrain_state())
    full = original_order(sim.scenario)
    short, whole = adapters.route_load(sim, full[:2]), adapters.route_load(sim, full)
    motor = desc.motor_names[-1]
    fault = (DescribedMotorFault(motor, 0.6),)
    r_short = adapters.route_risk(est, short, (), seed=3)
    r_whole = adapters.route_risk(est, whole, (), seed=3)
    r_fault = adapters.route_risk(est, whole, fault, seed=3)
    for r in (r_short, r_whole, r_fault):
        assert isinstance(r["failure_probability"], float) and 0.0 <= r["failure_probability"] <= 1.0
        assert set(r["landing_soc_packs"]) == set(desc.pack_names)
    assert 0.0 < r_whole["failure_probability"] < 1.0
    assert r_whole["failure_probability"] > r_short["failure_probability"]
    assert r_fault["failure_probability"] > r_whole["failure_probability"]
    assert r_short["landing_soc"]["p50"] > r_whole["landing_soc"]["p50"]
    # the fault is the description's motor; the paper's names are refused, not dropped
    with pytest.raises(ValueError, match=f"no motor 'aft' on this vehicle; have {', '.join(desc.motor_names)}"):
        adapters.route_risk(est, whole, (MotorFault("aft", 0.5),), seed=3)


def test_the_description_limits_decide_a_samples_failure():
    """A pack cut-off raised in the description fails samples that land under the preset's."""
    from gcs_pdm.vehicle.description import from_dict

    desc = PRESETS["quad-4s"]
    est = _described_estimator(desc, 16.0, 11.0)
    sim = VehicleSimulator(_pentagon(1200.0, 8.0), vehicle=desc, state=est.powertrain_state())
    load = adapters.route_load(sim, original_order(sim.scenario))
    base = adapters.route_risk(est, load, (), seed=1)
    data = desc.to_dict()
    data["packs"][0]["cutoff_v_per_cell"] = 3.85
    strict = from_dict(data)
    est_strict = _described_estimator(strict, 16.0, 11.0)
    tight = adapters.route_risk(est_strict, load, (), seed=1)
    assert base["failure_probability"] < tight["failure_probability"]
    assert "pack below cut-off voltage" in tight["failure_causes"]


def test_a_described_vehicles_proposal_carries_a_probability_not_unknown(tmp_path):
    """The plan executor assesses the chosen route and the current mission of a quad-4s."""
    svc, loop = _loop(tmp_path, "quad-4s")
    try:
        desc = PRESETS["quad-4s"]
        for t in range(1, 4):
            loop.process(PackFrame(float(t), "battery", 16.0, 11.0, 25.0))
            for m in desc.motor_names:
                loop.process(MotorFrame(float(t), m, 2.75, 5000.0, 30.0))
        snap = dataclasses.replace(loop.snapshot(), faults=(DescribedMotorFault("m2", 0.6),))
        assert snap.estimator is not None
        sim = VehicleSimulator(_pentagon(1800.0, 8.0), vehicle=desc, state=snap.state)
        full = original_order(sim.scenario)
        cands = [Candidate("planner", (1, 2), True, 30.0, 30.0, 30.0, None, {}),
                 Candidate("keep", tuple(range(1, 6)), False, 150.0, 150.0, -1.0, "pack depleted", {})]
        loads = {"planner": adapters.route_load(sim, full[:2]), "keep": adapters.route_load(sim, full)}
        out, chosen = loop.executor._assess_risk(snap, cands, cands[0], loads)
        keep = next(c for c in out if c.name == "keep")
        for c in (chosen, keep):
            assert "risk_unknown" not in c.extra
            assert 0.0 <= c.extra["failure_probability"] <= 1.0
            assert list(c.extra["landing_soc_packs"]) == ["battery"]
        assert keep.extra["failure_probability"] > chosen.extra["failure_probability"]
    finally:
        svc.close()
