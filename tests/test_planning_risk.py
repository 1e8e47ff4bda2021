"""Risk-bounded planning (issue 31, part 2; any vehicle, issue 32): routes × draws through the kernel,
the risk verdict, Algorithm 1 and the exact search on the risk-aware objective."""
from __future__ import annotations

import dataclasses
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.planning.exact import exact_search
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.plan import rank
from gcs_pdm.planning.planners import run_risk_bounded
from gcs_pdm.planning.risk import RiskSimulator, Uncertainty, draw
from gcs_pdm.planning.simulator import VehicleSimulator
from gcs_pdm.planning.table3_scenario import table3_scenario
from gcs_pdm.sim.truth import true_parameters

sys.path.insert(0, str(Path(__file__).parent))

NO_SPREAD = Uncertainty(soc_sd=0.0, temp_sd_c=0.0, param_rel_sigma=0.0, fault_sd=0.0, wind_sd_mps=0.0)


@pytest.fixture(scope="module")
def table3_10():
    return table3_scenario(true_parameters(), 10)


def _some_routes(n: int, count: int, seed: int = 0) -> list[tuple[int, ...]]:
    rng = np.random.default_rng(seed)
    return [tuple(int(w) for w in rng.permutation(n)[:rng.integers(0, 6)]) for _ in range(count)]


def test_without_spread_every_draw_is_the_deterministic_vehicle(table3_10):
    base = VehicleSimulator.for_scenario(table3_10.with_wind(3.0, -2.0))
    risk = RiskSimulator(base, draw(base, 3, uncertainty=NO_SPREAD, seed=0))
    routes = _some_routes(base.n, 40)
    det, rsk = base.evaluate(routes), risk.evaluate(routes)
    assert np.array_equal(det.feasible, rsk.feasible)
    np.testing.assert_allclose(rsk.final_soc, det.final_soc, atol=1e-9)
    np.testing.assert_allclose(rsk.power_cost, det.power_cost, rtol=1e-9)
    # a feasible route's expected reward is its reward (every draw gets home)
    np.testing.assert_allclose(rsk.reward, det.reward, atol=1e-9)


def test_carried_states_give_the_whole_route_numbers(table3_10):
    base = VehicleSimulator.for_scenario(table3_10)
    risk = RiskSimulator(base, draw(base, 40, seed=2))
    routes = [(4, 1), (4, 1, 7), (2,), ()]
    whole = risk.evaluate(routes)
    fresh = RiskSimulator(base, risk.draws)  # no memo
    for b, r in enumerate(routes):
        st = fresh.start_state(1)
        for w in r:
            st, _ = fresh.advance(st, np.array([w]))
        out = fresh.home(st)
        assert out.feasible[0] == whole.feasible[b]
        assert out.reward[0] == pytest.approx(whole.reward[b], abs=1e-12)
        np.testing.assert_allclose(out.final_soc[0], whole.final_soc[b], atol=1e-12)


def test_risk_plan_keeps_the_bound_where_the_nominal_plan_does_not(table3_10):
    base = VehicleSimulator.for_scenario(table3_10)
    risk = RiskSimulator(base, draw(base, 200, seed=5), max_failure_probability=0.02)
    nominal = particle_filter(base, particles=30, seed=0)
    nominal_risk = risk.risk_of(nominal.route)
    # the nominal plan promises the reserve but misses it on many draws
    assert nominal.feasible
    assert nominal_risk["landing_soc_quantiles"]["soc"][0] < table3_10.limits.landing_reserve_soc
    plan = run_risk_bounded("pf", risk, seed=0)
    r = plan.stats["risk"]
    assert plan.feasible and r["samples"] == 200
    assert r["p_failure"] <= 0.02
    assert r["landing_soc_quantiles"]["soc"][0] >= table3_10.limits.landing_reserve_soc
    assert plan.reward == pytest.approx(r["expected_reward"])


def test_exact_search_on_the_risk_objective_matches_brute_force():
    sc = table3_scenario(true_parameters(), 10)
    sc = sc.subset([w.number for w in sc.waypoints][:5])
    base = VehicleSimulator.for_scenario(sc)
    risk = RiskSimulator(base, draw(base, 24, seed=3), max_failure_probability=0.05)
    routes = [r for k in range(6) for r in itertools.permutations(range(base.n), k)]
    ev = RiskSimulator(base, risk.draws, max_failure_probability=0.05).evaluate(routes)
    obj = ev.objective()
    i = rank(np.where(ev.feasible, ev.reward, -1.0), np.where(ev.feasible, obj, -np.inf))
    best = exact_search(risk)
    assert best.reward == pytest.approx(float(ev.reward[i]), abs=1e-9)
    assert best.feasible == bool(ev.feasible[i])


def test_unsupported_vehicle_and_bad_settings_are_refused(table3_10):
    base = VehicleSimulator.for_scenario(table3_10)
    dr = draw(base, 4, seed=0)
    with pytest.raises(ValueError, match="max_failure_probability"):
        RiskSimulator(base, dr, max_failure_probability=1.5)
    with pytest.raises(ValueError, match="reserve_quantile"):
        RiskSimulator(base, dr, reserve_quantile=0.0)


def test_step_groups_cover_every_row_once_and_split_only_where_padding_costs_more_than_a_call():
    from gcs_pdm.planning.risk import CALL_COST_ROW_STEPS, _step_groups

    rows = np.arange(100, 400)
    steps = np.r_[np.full(150, 2), np.full(150, 40)][np.random.default_rng(0).permutation(300)]
    groups = _step_groups(rows, steps)
    flat = np.concatenate(groups)
    assert sorted(flat.tolist()) == rows.tolist()
    # 150 rows padded from 2 to 40 steps cost far more than one more call: two calls, each one length
    assert len(groups) == 2 and all(np.unique(steps[g - 100]).size == 1 for g in groups)
    # a few short rows among long ones: padding them is cheaper than a call of their own
    few = np.r_[np.full(3, 38), np.full(297, 40)]
    assert 3 * 2 < CALL_COST_ROW_STEPS and len(_step_groups(rows, few)) == 1
    assert _step_groups(rows[:0], steps[:0]) == []


def test_a_failed_draw_is_not_flown_on(table3_10):
    base = VehicleSimulator.for_scenario(table3_10)
    risk = RiskSimulator(base, draw(base, 8, seed=1))
    st = risk.start_state(1)
    failed = np.zeros((1, 8), dtype=bool)
    failed[0, [2, 5]] = True
    st = type(st)(**{**{f: getattr(st, f) for f in st.__dataclass_fields__}, "failed": failed})
    nxt = risk._fly(st, np.array([3]))
    assert np.array_equal(nxt.x[0, [2, 5]], st.x[0, [2, 5]]) and np.all(nxt.time_s[0, [2, 5]] == 0.0)
    assert np.all(nxt.time_s[0, [0, 1, 3, 4, 6, 7]] > 0.0) and nxt.failed[0, [2, 5]].all()


# --- any vehicle (issue 32): the description's packs, motors, topology and limits ------------------

@pytest.fixture(scope="module")
def faulted_presets():
    from test_planning_vehicle import _scenario  # five goals around the start, any vehicle
    from gcs_pdm.vehicle.presets import PRESETS

    out = {}
    for name, scale, airspeed in (("quad-4s", 1000.0, 8.0), ("hex-6s", 1000.0, 10.0), ("plane-3s", 3000.0, 20.0)):
        desc = PRESETS[name]
        out[name] = (VehicleSimulator(_scenario(scale, airspeed), vehicle=desc),
                     VehicleSimulator(_scenario(scale, airspeed), vehicle=desc,
                                      motor_faults={desc.motor_names[-1]: 0.6}))
    return out


@pytest.mark.parametrize("preset", ["quad-4s", "hex-6s", "plane-3s"])
def test_a_described_vehicle_is_drawn_and_flown_on_its_own_packs_and_motors(faulted_presets, preset):
    healthy, faulted = faulted_presets[preset]
    n_packs, n_motors = healthy._pp.shape[1], healthy._motor_rows.shape[1]
    routes = _some_routes(healthy.n, 12, seed=3)
    # without spread every draw is the deterministic vehicle (its topology, limits, reserve)
    flat = RiskSimulator(faulted, draw(faulted, 3, uncertainty=NO_SPREAD, seed=0))
    det, rsk = faulted.evaluate(routes), flat.evaluate(routes)
    assert np.array_equal(det.feasible, rsk.feasible)
    np.testing.assert_allclose(rsk.final_soc, det.final_soc, atol=1e-9)
    assert rsk.final_soc.shape == (len(routes), n_packs) and rsk.final_motor_temp.shape == (len(routes), n_motors)
    # with spread: the draws are the description's shapes; its motors (one type) share one draw
    dr = draw(faulted, 64, seed=1)
    assert dr.x0.shape == (64, n_packs, 4) and dr.motor_params.shape == (64, n_motors, 5)
    assert dr.fault.shape == (64, n_motors) and np.all(dr.fault[:, :-1] == 0) and dr.fault[:, -1].std() > 0
    assert np.all(dr.motor_params == dr.motor_params[:, :1]) and dr.motor_params[:, 0, 0].std() > 0
    # the same draws with and without the fault: the fault can only cost charge
    whole = [tuple(range(healthy.n))]
    calm = RiskSimulator(healthy, dataclasses.replace(dr, fault=np.zeros_like(dr.fault))).evaluate(whole)
    hurt = RiskSimulator(faulted, dr).evaluate(whole)
    assert hurt.final_soc[0].min() < calm.final_soc[0].min()
    plan = run_risk_bounded("pf", RiskSimulator(faulted, draw(faulted, 40, seed=2)), particles=10, seed=0)
    risk = plan.stats["risk"]
    assert 0.0 <= risk["p_failure"] <= 1.0 and risk["samples"] == 40
    q = risk["landing_soc_quantiles"]["soc"]
    assert 0.0 <= q[0] <= q[1] <= q[2] <= 1.0
    assert list(plan.to_dict()["final_soc"]) == list(healthy.vehicle.pack_names)
