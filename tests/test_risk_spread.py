"""The risk planner's parameter spread comes from what the estimator knows (not a fixed 5 %), and
its landing-SoC p05–p95 then holds truths spread like the simulated vehicle's hidden truth."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.estimation import calibration
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.frames import PackFrame
from gcs_pdm.models import kernel
from gcs_pdm.models.powertrain import PowertrainState
from gcs_pdm.planning.planners import run_risk_bounded
from gcs_pdm.planning.risk import (PRIOR_PARAM_REL_SIGMA, RiskSimulator, Uncertainty, draw, prior_spread,
                                   spread_from_estimator)
from gcs_pdm.planning.scenario import Home, Scenario, StartState, Waypoint
from gcs_pdm.planning.simulator import VehicleSimulator
from gcs_pdm.service.adapters import _estimated_start
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS

#: the standard deviation of the simulated vehicle's hidden truth (±15 % log-uniform)
TRUTH_PARAM_SD = 0.0866


def _simulator(name: str, soc: float = 0.6) -> VehicleSimulator:
    """Ten goals within two minutes' flight (benchmarks/bench_risk_presets.py's field), a motor at
    60 % power loss."""
    desc = PRESETS[name]
    rng = np.random.default_rng(0)
    reach, alt = 120.0 * desc.cruise_speed_mps, 40.0 if desc.airframe.type == "multirotor" else 100.0
    r, a = reach * np.sqrt(rng.uniform(0.1, 1.0, 10)), rng.uniform(0.0, 2 * np.pi, 10)
    wps = tuple(Waypoint(i + 1, float(r[i] * np.cos(a[i])), float(r[i] * np.sin(a[i])), alt,
                         reward=float(rng.integers(1, 10)), airspeed_mps=desc.cruise_speed_mps) for i in range(10))
    start = StartState(0.0, 0.0, alt, pack_temp_c=(20.0,) * 4, motor_temp_c=(20.0,) * 2, pack_soc=(1.0,) * 4)
    sc = Scenario(name=f"field_{name}", home=Home(), start=start, waypoints=wps,
                  return_airspeed_mps=desc.cruise_speed_mps, max_climb_rate_mps=desc.climb_rate_mps)
    inputs = model_inputs(desc)
    state = PowertrainState(kernel.initial_pack_state(inputs.pack_matrix, soc, 20.0),
                            np.full(inputs.n_motors, 20.0))
    return VehicleSimulator(sc, vehicle=desc, state=state,
                            motor_faults={desc.motor_names[min(1, len(desc.motor_names) - 1)]: 0.6})


@pytest.fixture(scope="module")
def quad_estimator():
    """quad-4s's estimator after a few seconds at rest and under load: its calibrators initialised."""
    desc = PRESETS["quad-4s"]
    est = StateEstimator(vehicle=desc)
    for k in range(20):
        est.consume(PackFrame(k + 1.0, "battery", 16.4 - (0.3 if k >= 10 else 0.0), 0.0 if k < 10 else 20.0, None))
    return est


def test_a_self_calibrated_pack_is_drawn_from_what_it_learned_on_the_prior(quad_estimator):
    est = quad_estimator
    cal = est.calib[0]
    # nothing learned yet (the posterior is the calibrator's loose prior): the prior, as for any pack
    cal.P[calibration.I_G, calibration.I_G] = cal.prior.capacity_rel_sd ** 2
    cal.P[calibration.I_R0, calibration.I_R0] = (cal.prior.r0_rel_sd * cal.r0p) ** 2
    cal.x[calibration.I_G], cal.x[calibration.I_R0] = 1.0, cal.r0p
    unlearned = spread_from_estimator(est)
    np.testing.assert_allclose(unlearned.pack_log_sd, PRIOR_PARAM_REL_SIGMA)
    np.testing.assert_allclose(unlearned.pack_scale, 1.0)

    # what a flight taught it: g = 1.25 ± 0.1 from its prior 1 ± 0.25 (precision 100 = 16 from the prior
    # + 84 learned), R0 1.5 ± 0.45 × its prior (± 1.0). On the 8 % prior (precision 156.25): g =
    # (156.25 + 1.25·100 − 16) / 240.25 = 1.10406 ± 0.064517, R0 = 1.015423 ± 0.079012 × its prior
    cal.x[calibration.I_G], cal.P[calibration.I_G, calibration.I_G] = 1.25, 0.1 ** 2
    cal.x[calibration.I_R0] = 1.5 * cal.r0p
    cal.P[calibration.I_R0, calibration.I_R0] = (0.45 * cal.r0p) ** 2
    spread = spread_from_estimator(est)
    assert spread.learned == (True,)
    for k in (kernel.I_CB, kernel.I_QMAX, kernel.I_CMAX):
        assert spread.pack_scale[0, k] == pytest.approx(1 / 1.10406, rel=1e-4)
        assert spread.pack_log_sd[0, k] == pytest.approx(0.064517 / 1.10406, rel=1e-3)
    for k in (kernel.I_RS, kernel.I_RCP0):
        assert spread.pack_scale[0, k] == pytest.approx(1.015423, rel=1e-4)
        assert spread.pack_log_sd[0, k] == pytest.approx(0.079012 / 1.015423, rel=1e-3)
    assert spread.pack_log_sd[0, kernel.I_CT] == PRIOR_PARAM_REL_SIGMA
    assert spread.pack_scale[0, kernel.I_CT] == 1.0

    # the draws: C_max about that centre with that spread; the start SoC kept
    sim = _simulator("quad-4s")
    d = draw(sim, 4000, seed=1, spread=spread)
    log_cap = np.log(d.pack_params[:, 0, kernel.I_CMAX] / sim._pp[0][0, kernel.I_CMAX])
    assert np.median(log_cap) == pytest.approx(-np.log(1.10406), abs=0.01)
    assert np.std(log_cap) == pytest.approx(spread.pack_log_sd[0, kernel.I_CMAX], rel=0.1)
    soc = kernel.state_of_charge(d.pack_params[:, 0], d.x0[:, 0])
    assert np.mean(soc) == pytest.approx(0.6, abs=0.005)


def test_a_fitted_pack_gets_the_prior_and_keeps_the_capacity_term_in_its_soc():
    desc = PRESETS["edge540"]  # packs described as fitted: no calibrator
    est = StateEstimator(vehicle=desc)
    spread = spread_from_estimator(est)
    assert spread.learned == (False,) * 4
    np.testing.assert_array_equal(spread.pack_log_sd, PRIOR_PARAM_REL_SIGMA)
    np.testing.assert_array_equal(spread.pack_scale, 1.0)
    with pytest.raises(ValueError, match="packs"):
        draw(_simulator("quad-4s"), 4, spread=spread)


def test_the_estimated_start_counts_a_calibrated_packs_capacity_once(quad_estimator):
    sim = _simulator("quad-4s")
    start = _estimated_start(quad_estimator, sim)
    cmax = quad_estimator.packs.params[0, kernel.I_CMAX]
    # the calibrator's SoC σ, as the estimate shows it, without the parameter set's capacity term
    assert np.sqrt(start["pack_cov"][0, kernel.S_QB, kernel.S_QB]) / cmax == pytest.approx(
        quad_estimator.estimate(details=False).soc_sd[0], rel=1e-6)
    assert start["spread"].learned == (True,)
    assert _estimated_start(None, sim)["spread"].learned == (False,)


def test_the_landing_interval_holds_truths_spread_like_the_simulated_vehicle():
    """plane-3s was the worst preset at the fixed 5 %: 77.3 % of truths spread by 8.7 % landed
    inside its p05–p95 (docs/notes/2026-11-27-risk-presets.md). With the prior spread, 85–95 %."""
    sim = _simulator("plane-3s")
    covered = {}
    for name, spread in (("fixed", None), ("prior", prior_spread(1))):
        plan = run_risk_bounded("pf", RiskSimulator(sim, draw(sim, 200, seed=0, spread=spread)), seed=0)
        lo, _, hi = plan.stats["risk"]["landing_soc_quantiles"]["soc"]
        truths = RiskSimulator(sim, draw(sim, 400, uncertainty=Uncertainty(param_rel_sigma=TRUTH_PARAM_SD),
                                         seed=10_000))
        st = truths.start_state(1)
        for w in list(plan.route) + [truths.landing_node]:
            st = truths._fly(st, np.array([w]))
        assert not st.failed.any()
        low = truths._soc(st.x)[0].min(axis=1)
        covered[name] = float(np.mean((low >= lo) & (low <= hi)))
    assert covered["fixed"] < 0.85  # what was wrong
    assert 0.85 <= covered["prior"] <= 0.95, covered
