"""The estimator's model-consistency test: silent on packs that match their model, raised (with its
evidence, a refit suggestion and a wider prediction) on a pack that does not, cleared once the pack
is modelled right again; the diagnoser's advisory, /status's summary, the fault tracker."""
import copy
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from gcs_pdm.diagnosis.faults import ADVISORY_TYPES, MODEL_MISMATCH, MOTOR_POWER_LOSS, Fault
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.pack_filter import clipped_chi2_moments, clipped_mean_quantile
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
from gcs_pdm.estimation.synthetic import PackDegradation, fly_synthetic
from gcs_pdm.frames import PackFrame
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.models.params import default_set
from gcs_pdm.service.fault_tracker import FaultTracker
from gcs_pdm.service.status_report import model_mismatch_summary
from gcs_pdm.sim.truth import true_parameters

FLIGHTS = Path(__file__).resolve().parent.parent / "fixtures" / "flights"
#: the mismatched pack: 60 % more series resistance than the parameter set the estimator runs on
RISE = 1.6


def test_clipped_chi2_bound_matches_monte_carlo():
    z = np.random.default_rng(0).standard_normal((20000, 120))
    sq = np.minimum(z * z, 9.0)
    m1, var = clipped_chi2_moments(3.0)
    assert m1 == pytest.approx(sq.mean(), abs=0.01) and var == pytest.approx(sq.var(), rel=0.03)
    means = sq.mean(axis=1)
    for q in (0.5, 0.99, 0.999):
        assert clipped_mean_quantile(q, 120, 3.0) == pytest.approx(np.quantile(means, q), abs=0.015)
    # without a clip it is the χ² bound itself
    assert clipped_mean_quantile(0.999, 120, 50.0) == pytest.approx(chi2.ppf(0.999, 120) / 120, rel=1e-6)


def watch(est, frames, until_s=np.inf):
    """Feed frames up to ``until_s``; the largest window statistic seen per pack (voltage, temperature)."""
    worst = np.full((len(est.pack_names), 2), -np.inf)
    rest = []
    for k, fr in enumerate(frames):
        if fr.time_s > until_s:
            rest = frames[k:]
            break
        est.consume(fr)
        if isinstance(fr, PackFrame):
            np.fmax(worst, est.packs.consistency.statistic(), out=worst)
    return worst, rest


@pytest.mark.parametrize("k", range(3))
def test_no_false_alarm_on_nominal_flights(k):
    """The detection table's fault-free flights: a vehicle whose every parameter is up to 15 % off
    the set, sensor noise, spikes, drop-outs and an 8 s outage — noise, not a model that fails."""
    flight = fly_synthetic(true_parameters(2013 + k), np.random.default_rng(100 + k), duration_s=1200.0,
                           initial_soc=float(np.random.default_rng(k).uniform(0.85, 1.0)))
    est = StateEstimator(default_set())
    worst, _ = watch(est, flight.frames)
    bound = est.packs.consistency.raise_at
    assert np.all(np.isfinite(worst)) and np.all(worst < bound), (worst, bound)
    assert est.counters["model_mismatch_raised"] == 0
    assert all(c["state"] == "matches" for c in est.estimate().model_mismatch.values())


def test_no_false_alarm_on_the_recorded_flights():
    """The simulated vehicle's tlogs (fixtures/flights: coarse 5 s message time, three motor
    faults): nothing raised; the flights long enough to fill the window are judged."""
    judged = 0
    for tlog in sorted(FLIGHTS.glob("*.tlog")):
        est = StateEstimator(default_set())
        replay_tlog(tlog, frame_consumer=est.consume)
        assert est.counters["model_mismatch_raised"] == 0, tlog.name
        checks = est.estimate().model_mismatch
        judged += all(c["state"] == "matches" for c in checks.values())
        assert all(c["state"] in ("matches", "unknown") for c in checks.values())
    assert judged >= 8


@pytest.fixture(scope="module")
def mismatched_flight():
    return fly_synthetic(default_set(), np.random.default_rng(300), duration_s=900.0,
                         degradation=(PackDegradation("LLF20", resistance=RISE),))


def test_mismatch_raised_with_evidence_widens_prediction_and_clears_when_matched(mismatched_flight):
    est = StateEstimator(default_set())
    _, rest = watch(est, mismatched_flight.frames, until_s=400.0)
    e = est.estimate()
    check = e.model_mismatch["LLF20"]
    assert check["active"] and check["state"] == "mismatch", check
    assert [e.model_mismatch[n]["active"] for n in ("ULA20", "LRF40", "URA40")] == [False] * 3
    assert check["statistic"] > check["bound"] > 1.0 and check["window_updates"] == 120
    assert check["channels"] == ["voltage"] and abs(check["voltage_residual_mv"]) < 1000
    assert check["temperature_residual_k"] is not None and check["false_alarm_per_window"] == pytest.approx(1e-4)
    assert 60.0 < check["since_s"] < 400.0
    assert "gcs-pdm fit battery --pack LLF20" in check["suggestion"] and "LLF20" in check["reason"]
    assert check["prediction_inflation"] == pytest.approx(check["statistic"], rel=0.05)
    json.dumps(e.to_dict())  # the evidence is JSON-ready
    assert e.to_dict()["packs"]["LLF20"]["model_mismatch"]["active"]

    # the prediction starts from a wider state: the same draws give a wider time to cut-off
    load = FutureLoad.constant(900.0, 3600.0, 10.0)
    plain = copy.deepcopy(est)
    plain._mismatch_active = [False] * len(plain.pack_names)
    assert np.all(plain.prediction_inflation() == 1.0) and est.prediction_inflation()[0] > 1.0
    wide = predict_from_estimator(est, load, rng=np.random.default_rng(1), n_samples=200, stop_on_failure=False,
                                  trajectories=False, param_rel_sigma=0.0)
    narrow = predict_from_estimator(plain, load, rng=np.random.default_rng(1), n_samples=200, stop_on_failure=False,
                                    trajectories=False, param_rel_sigma=0.0)
    spread = lambda p: p.pack_time_to_cutoff_s[0, 2] - p.pack_time_to_cutoff_s[0, 0]  # noqa: E731
    assert spread(wide) > 1.1 * spread(narrow)

    # refitted (here: the true resistance adopted), the pack matches its model again
    est.adopt_pack_scales("LLF20", RISE, 1.0)
    watch(est, rest)
    assert not est.model_mismatch_active.any()
    assert est.counters["model_mismatch_cleared"] >= 1
    assert est.estimate().model_mismatch["LLF20"]["state"] == "matches"


def test_diagnoser_raises_the_advisory_with_the_evidence(mismatched_flight):
    p = DiagnosisPipeline(default_set())
    for fr in mismatched_flight.frames:
        p(fr)
    advisories = [f for f in p.faults if f.type == MODEL_MISMATCH]
    assert [f.component for f in advisories] == ["LLF20"], [f.to_dict() for f in p.faults]
    f = advisories[0]
    assert f.time_s >= f.evidence["since_s"] + 10.0 - 1e-6  # debounced
    assert f.magnitude > f.evidence["bound"] and 0.5 <= f.confidence <= 1.0
    assert "gcs-pdm fit battery" in f.evidence["suggestion"] or not f.active
    assert not [x for x in p.faults if x.type == MOTOR_POWER_LOSS]
    report = json.loads(json.dumps(p.report()))
    assert any(e["event"] == "raise" and e["type"] == MODEL_MISMATCH for e in report["events"])
    assert Fault.from_dict(report["faults"][[x["type"] for x in report["faults"]].index(MODEL_MISMATCH)]).key == f.key


def test_status_summary_says_which_pack_why_and_what_to_do():
    est = StateEstimator(default_set())
    assert model_mismatch_summary(est.estimate().model_mismatch) is None  # nothing judged: nothing said
    checks = {"A": {"active": False, "state": "matches"},
              "B": {"active": True, "reason": "pack B does not behave like its model", "since_s": 12.0,
                    "prediction_inflation": 2.5, "suggestion": "fit this pack on recent logs: gcs-pdm fit battery x"}}
    s = model_mismatch_summary(checks)
    assert s["packs"] == ["B"] and s["since_s"] == {"B": 12.0}
    assert "pack B does not behave" in s["reason"] and "gcs-pdm fit battery" in s["reason"] and "×2.50" in s["reason"]


def test_an_advisory_is_stored_and_published_but_is_no_reason_to_replan():
    stored, published = [], []
    service = SimpleNamespace(
        store=SimpleNamespace(add_fault=lambda f, src: stored.append(f) or len(stored), clear_fault=lambda fid: None),
        events=SimpleNamespace(publish=lambda event, **kw: published.append((event, kw))),
        state=SimpleNamespace(update_nested=lambda *a, **k: None))
    faults = [Fault(MODEL_MISMATCH, "LLF20", 2.0, 10.0, 0.6, {}), Fault(MOTOR_POWER_LOSS, "fwd", 0.4, 10.0, 0.9, {})]
    tracker = FaultTracker(service, SimpleNamespace(active_faults=lambda: faults, motor_names=("fwd", "aft")))
    new = tracker.check(11.0)
    assert MODEL_MISMATCH in ADVISORY_TYPES
    assert [f.type for f in new] == [MOTOR_POWER_LOSS]
    assert {f.type for f in stored} == {MODEL_MISMATCH, MOTOR_POWER_LOSS}
    assert any(kw.get("kind") == MODEL_MISMATCH for _, kw in published)
