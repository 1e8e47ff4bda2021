"""The prognosis re-uses its latest prediction only while it still holds, and says how old it is.

An estimator that has flown 300 s of a synthetic flight is held still (no more frames) while the
monitor checks every 30 s of message time over a light constant load: the state then follows the
prediction (its SoC drop is tiny), so checks re-use it; moving the state, the faults, the mission
or the parameters — or waiting ``max_age_s`` — makes the next check run the Monte Carlo again.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gcs_pdm.diagnosis.prognosis import PrognosisConfig, PrognosisMonitor
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.estimation.synthetic import fly_synthetic
from gcs_pdm.models import kernel
from gcs_pdm.models.params import default_set
from gcs_pdm.sim.truth import true_parameters

NO_FAULT = np.zeros(2)


@pytest.fixture(scope="module")
def flown():
    flight = fly_synthetic(true_parameters(), np.random.default_rng(31), duration_s=300.0)
    est = StateEstimator(default_set())
    for fr in flight.frames:
        est.consume(fr)
    assert est.ready()
    return est


@pytest.fixture
def est(flown):
    """A copy of the flown estimator's pack state to disturb (restored afterwards)."""
    mean, cov = flown.packs.mean.copy(), flown.packs.cov.copy()
    yield flown
    flown.packs.mean[:], flown.packs.cov[:] = mean, cov


def monitor(est, **cfg) -> tuple[PrognosisMonitor, float]:
    m = PrognosisMonitor(config=PrognosisConfig(warmup_s=0.0, n_samples=40, **cfg), seed=3)
    t0 = est.time_s
    m.set_mission(FutureLoad.constant(300.0, 1200.0, 2.0), t0)
    return m, t0


def checks(m, est, times, fault=NO_FAULT) -> list[int]:
    """The number of Monte Carlo runs after each check."""
    out = []
    for t in times:
        m.check(t, est, fault)
        out.append(m.runs)
    return out


def test_a_prediction_that_holds_is_reused_and_says_how_old_it_is(est):
    m, t0 = monitor(est)
    assert checks(m, est, [t0, t0 + 30.0, t0 + 60.0, t0 + 90.0]) == [1, 1, 1, 1]
    assert m.last_run_reason == "mission" and m.reused == 3
    status = m.status(t0 + 100.0)
    assert status["predicted_at_s"] == pytest.approx(t0, abs=1e-3)
    assert status["age_s"] == pytest.approx(100.0, abs=1e-3)
    assert status["runs"] == 1 and status["reused"] == 3 and status["latest"]["p_failure"] == m.latest_prediction.p_failure


def test_a_state_that_jumps_out_of_the_band_re_runs_the_prediction(est):
    m, t0 = monitor(est)
    checks(m, est, [t0, t0 + 30.0])
    assert m.runs == 1
    # a voltage correction of 10 % of one pack's capacity: far outside the prediction's band
    est.packs.mean[2, kernel.S_QB] -= 0.10 * est.packs.params[2, kernel.I_CMAX]
    checks(m, est, [t0 + 60.0])
    assert m.runs == 2 and m.last_run_reason == "out of band"
    assert m.status(t0 + 60.0)["age_s"] == 0.0
    # the new prediction starts from the moved state: it holds again
    checks(m, est, [t0 + 90.0])
    assert m.runs == 2


def test_a_move_within_the_band_does_not_re_run(est):
    m, t0 = monitor(est, band_soc=0.02, band_sds=0.0)
    checks(m, est, [t0])
    est.packs.mean[2, kernel.S_QB] -= 0.005 * est.packs.params[2, kernel.I_CMAX]
    assert checks(m, est, [t0 + 30.0]) == [1]


def test_changed_faults_mission_parameters_or_age_re_run_it(est):
    m, t0 = monitor(est, max_age_s=110.0)
    checks(m, est, [t0, t0 + 30.0])
    checks(m, est, [t0 + 60.0], fault=np.array([0.01, 0.0]))      # within rerun_fault_change
    assert m.runs == 1
    checks(m, est, [t0 + 90.0], fault=np.array([0.3, 0.0]))
    assert (m.runs, m.last_run_reason) == (2, "faults")
    m.set_mission(FutureLoad.constant(250.0, 900.0, 2.0), t0 + 100.0)
    checks(m, est, [t0 + 120.0], fault=np.array([0.3, 0.0]))
    assert (m.runs, m.last_run_reason) == (3, "mission")
    m.reset_baseline()  # what the pipeline calls when the estimator adopts a degraded pack
    checks(m, est, [t0 + 150.0], fault=np.array([0.3, 0.0]))
    assert (m.runs, m.last_run_reason) == (4, "parameters")
    checks(m, est, [t0 + 180.0, t0 + 240.0], fault=np.array([0.3, 0.0]))
    assert m.runs == 4
    checks(m, est, [t0 + 270.0], fault=np.array([0.3, 0.0]))
    assert (m.runs, m.last_run_reason) == (5, "age")


def test_a_pending_limit_fault_gets_a_fresh_prediction_at_each_check_then_one_is_reused(est):
    # a load the packs cannot carry: P(fail) >= 0.5 from the first check
    m = PrognosisMonitor(config=PrognosisConfig(warmup_s=0.0, n_samples=40), seed=3)
    t0 = est.time_s
    m.set_mission(FutureLoad.constant(6000.0, 1800.0, 2.0), t0)
    times = [t0 + 30.0 * k for k in range(6)]
    runs, events = [], []
    for t in times:
        events += m.check(t, est, NO_FAULT)
        runs.append(m.runs)
    # debounced over 60 s: three checks, each on its own prediction; raised at the third
    limit = [(ev, f) for ev, f in events if f.type == "predicted_limit_violation"]
    assert [ev for ev, _ in limit] == ["raise"] and limit[0][1].time_s == pytest.approx(times[2])
    assert runs == [1, 2, 3, 3, 3, 3], runs
    assert m.last_run_reason == "limit pending"
    # once raised (and still holding) the prediction is re-used: its times to failure count from now
    f = m.faults[("predicted_limit_violation", "vehicle")]
    age = times[-1] - times[2]
    assert f.updated_s == pytest.approx(times[-1]) and f.evidence["prediction_age_s"] == pytest.approx(age, abs=0.1)
    ttf = m.latest_prediction.time_to_failure_s
    assert math.isfinite(ttf[1])
    assert f.evidence["time_to_failure_s_median"] == pytest.approx(max(ttf[1] - age, 0.0), abs=0.1)


def test_an_undecided_p_failure_gets_fresh_draws_at_each_check(est):
    m, t0 = monitor(est)
    checks(m, est, [t0, t0 + 30.0])
    assert m.runs == 1 and m.latest_prediction.p_failure < m.config.p_clear
    # as if the prediction had said 0.3: between p_clear and p_raise the Monte Carlo's noise decides
    m.latest_prediction = replace(m.latest_prediction, p_failure=0.3)
    checks(m, est, [t0 + 60.0])
    assert (m.runs, m.last_run_reason) == (2, "p_failure undecided")
