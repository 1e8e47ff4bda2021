"""A fitted pack's set is a prior (issue 29, ``estimation.fitted_prior``): edge540 flown with a pack
off its fitted set is taken over by the self-calibrating filter; a pack that is its set keeps the
paper filter's figures exactly."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from gcs_pdm.estimation.estimator import EstimatorConfig, StateEstimator
from gcs_pdm.replay.calibration_eval import simulated_case

FLIGHT_S = 400.0


def _fly(case):
    """(time, SoC, σ, truth) per sample of ``case`` through its estimator."""
    out = []
    for k in range(case.end):
        case.feed(k)
        e = case.estimator.estimate(details=False)
        out.append(((k + 1) * case.dt, e.soc[0], e.soc_sd[0], case.truth_run.soc[0, k]))
    return np.array(out)


def test_edge540_with_a_pack_of_twice_its_sets_resistance_is_within_005_after_120_s(caplog):
    case = simulated_case("edge540", capacity_scale=0.8, resistance_scale=2.0, start_soc=0.9, seed=4,
                          duration_s=FLIGHT_S)
    with caplog.at_level(logging.WARNING):
        t, soc, sd, truth = _fly(case).T
    watch = case.estimator.fitted_watch[0]
    # the set is contradicted early in the flight (30 s of rest, then legs), and says why
    assert 30.0 < watch.contradicted_at_s < 150.0
    assert "contradicts the fitted set" in watch.reason
    assert case.estimator.calib[0] is watch.calibrator
    # the set no longer describes the pack: the model-mismatch advisory says so, and to refit it
    check = case.estimator.model_check(0)
    assert check["fitted_set"]["reason"] == watch.reason
    assert check["state"] == "mismatch" and watch.reason in check["reason"] and "fit this pack" in check["suggestion"]
    late = t >= 150.0  # 120 s of flight after 30 s of rest
    err = np.abs(soc[late] - truth[late])
    assert err.max() <= 0.05
    assert np.mean(err <= 2.0 * sd[late]) >= 0.9
    # without the watch the paper filter reads the sag as charge: far off
    paper = simulated_case("edge540", capacity_scale=0.8, resistance_scale=2.0, start_soc=0.9, seed=4,
                           duration_s=FLIGHT_S)
    paper.estimator = StateEstimator(vehicle=paper.description, config=EstimatorConfig(fitted_set_as_prior=False))
    tp, socp, _, truthp = _fly(paper).T
    assert np.abs(socp[tp >= 150.0] - truthp[tp >= 150.0]).max() > 0.2


def test_a_small_pack_taken_over_by_the_sets_innovations_keeps_the_sets_curve():
    """A pack 0.7x its set's capacity: the set's innovations contradict it, but its curve is the
    set's, so the filter that takes over stays on it (the curve check does not restart it from the
    chemistry's curves, which read it 0.3 off) and stays within 0.05."""
    case = simulated_case("edge540", capacity_scale=0.7, resistance_scale=1.0, start_soc=0.8, seed=7,
                          duration_s=FLIGHT_S)
    t, soc, sd, truth = _fly(case).T
    watch = case.estimator.fitted_watch[0]
    assert "innovations" in watch.reason and watch.curve_reason is None
    assert case.estimator.calib[0] is watch.calibrator
    assert np.abs(soc[t >= 150.0] - truth[t >= 150.0]).max() <= 0.05


def test_a_pack_that_is_its_set_keeps_the_paper_filters_figures_exactly():
    start = 0.75
    case = simulated_case("edge540", capacity_scale=1.0, resistance_scale=1.0, start_soc=start, seed=3,
                          duration_s=FLIGHT_S)
    watched = _fly(case)
    assert np.isnan(case.estimator.fitted_watch[0].contradicted_at_s)
    assert case.estimator.calib[0] is None
    plain = simulated_case("edge540", capacity_scale=1.0, resistance_scale=1.0, start_soc=start, seed=3,
                           duration_s=FLIGHT_S)
    plain.estimator = StateEstimator(vehicle=plain.description, config=EstimatorConfig(fitted_set_as_prior=False))
    np.testing.assert_array_equal(watched, _fly(plain))


def test_a_curve_contradicted_pack_restarts_from_its_chemistry_at_the_last_rest_less_the_charge_counted():
    """``FittedPackWatch.chemistry_filter``: the chemistry's curves read the last settled rest's
    voltage (not the first reading's), and the charge drawn since moves the SoC; the σ is the
    never-fitted LiPo's (at least the family's 0.08), not the set's filter's."""
    from gcs_pdm.estimation.curve_bank import CurveBank
    from gcs_pdm.estimation.fitted_prior import BY_INNOVATIONS
    from gcs_pdm.models.chemistry import chemistry

    est = StateEstimator()
    watch = est.fitted_watch[0]
    cells, q_c = watch.chemistry_prior.cells, watch.chemistry_prior.capacity_c
    lipo = chemistry("lipo")
    rest_v, current = cells * lipo.ocv(0.8), 30.0
    watch.initialise(0.0, rest_v + 1.0, 0.0, 25.0)  # a first reading the rest then corrects
    for k in range(1, 31):
        watch.step(float(k), 1.0, 0.0, rest_v, 25.0)
    soc, t = 0.8, 30.0
    for k in range(31, 131):
        soc -= current / q_c
        t = float(k)
        watch.step(t, 1.0, current, cells * lipo.ocv(soc) - 0.05 * current, 25.0)
    watch.contradicted_by = BY_INNOVATIONS
    cal = watch.chemistry_filter(t, current, cells * lipo.ocv(soc) - 0.05 * current, 25.0)
    assert isinstance(cal, CurveBank) and cal.lead.chem.name == "lipo"
    drawn = 100 * current / q_c
    assert cal.soc == pytest.approx(0.8 - drawn, abs=0.03)
    assert 0.08 <= cal.soc_sd <= 0.3
