"""Monte Carlo prediction: wiring against a deterministic kernel run, faults, uncertainty."""
import numpy as np
import pytest

from gcs_pdm.estimation.prediction import FutureLoad, predict, restate, sample_parameters
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import default_set
from gcs_pdm.models.powertrain import Limits, MotorFault, PowertrainState, fly


def setup(soc=0.5):
    ps = default_set()
    st = PowertrainState.full(ps, temp_c=25.0, soc=soc)
    return ps, st


def test_without_uncertainty_it_is_the_kernel_run():
    ps, st = setup()
    load = FutureLoad.constant(1200.0, 1800.0, 1.0, ambient_c=20.0)
    cov = np.tile(np.eye(4) * 1e-12, (4, 1, 1))
    pred = predict(ps, st.pack_state, cov, st.motor_temp_c, np.zeros(2), load, rng=np.random.default_rng(0),
                   n_samples=5, param_rel_sigma=0.0, fault=np.array([0.5, 0.0]))
    ref = fly(ps, st, load.dt, load.shaft_power_w, 20.0, faults=[MotorFault("fwd", 0.5)], record=False)
    t_ref = float(np.cumsum(load.dt)[ref.fail_step[0]])
    assert pred.p_failure == 1.0
    assert pred.time_to_failure_s == pytest.approx([t_ref] * 3, abs=1.5)
    assert pred.peak_motor_temp_c[1, 1] == pytest.approx(ref.max_motor_temp[0, 1], abs=1e-3)
    assert pred.failure_causes == {kernel.FAILURE_NAMES[int(ref.fail_cause[0])]: 5}


def test_fault_shortens_and_uncertainty_spreads():
    ps, st = setup(0.6)
    load = FutureLoad.constant(1000.0, 1800.0, 2.0)
    cov = np.tile(np.diag([300.0 ** 2, 10.0, 1.0, 0.5]), (4, 1, 1))
    args = (ps, st.pack_state, cov, st.motor_temp_c, np.ones(2), load)
    healthy = predict(*args, rng=np.random.default_rng(1), n_samples=100)
    faulted = predict(*args, rng=np.random.default_rng(1), n_samples=100, fault=np.array([0.0, 0.7]))
    assert faulted.time_to_failure_s[1] < healthy.time_to_failure_s[1] - 100
    # the aft motor is faulted, so the fwd one carries the load: it runs hotter
    assert faulted.peak_motor_temp_c[0, 1] > faulted.peak_motor_temp_c[1, 1] + 5
    tight = predict(*args, rng=np.random.default_rng(1), n_samples=100, param_rel_sigma=0.01)
    spread = lambda p: p.time_to_failure_s[2] - p.time_to_failure_s[0]
    assert spread(healthy) > spread(tight) > 0
    d = healthy.to_dict()
    assert set(d["packs"]) == {"LLF20", "ULA20", "LRF40", "URA40"} and d["n_samples"] == 100


def test_feasible_load_does_not_fail():
    ps, st = setup(0.9)
    load = FutureLoad.constant(800.0, 600.0, 5.0)
    pred = predict(ps, st.pack_state, np.tile(np.eye(4), (4, 1, 1)), st.motor_temp_c, np.ones(2), load,
                   rng=np.random.default_rng(2), n_samples=50, limits=Limits())
    assert pred.p_failure == 0.0 and np.isinf(pred.time_to_failure_s).all()
    assert pred.soc_median.shape == (pred.time_s.size, 4) and 55 <= pred.time_s.size <= 62
    assert np.all(np.diff(pred.time_s) > 0) and np.all(pred.soc_median[-1] < pred.soc_median[0])


def test_restate_keeps_soc_fraction_and_voltages():
    ps, st = setup(0.7)
    pp, _ = sample_parameters(ps, 20, np.random.default_rng(3), 0.1)
    x = restate(ps.pack_matrix(), np.broadcast_to(st.pack_state, (20, 4, 4)), pp)
    assert np.allclose(kernel.state_of_charge(pp, x), 0.7)
    assert np.all(pp[..., kernel.I_CMAX] <= pp[..., kernel.I_QMAX])


def test_future_load_validation_and_after():
    with pytest.raises(ValueError, match="dt"):
        FutureLoad(np.array([1.0, -1.0]), np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="one length"):
        FutureLoad(np.ones(3), np.ones(2))
    load = FutureLoad(np.full(10, 2.0), np.arange(10.0))
    rest = load.after(5.0)
    assert rest.duration_s == pytest.approx(15.0) and rest.shaft_power_w[0] == 2.0
    assert load.after(0.0).duration_s == 20.0 and load.after(25.0).dt.size == 0


def test_load_for_route_follows_the_planner_and_predicts_its_outcome():
    from pathlib import Path

    from gcs_pdm.estimation.prediction import load_for_route
    from gcs_pdm.planning.scenario import Scenario
    from gcs_pdm.planning.simulator import VehicleSimulator

    root = Path(__file__).resolve().parent.parent / "fixtures" / "scenarios"
    scenario = Scenario.from_json((root / "table3_10.json").read_text())
    sim = VehicleSimulator.for_scenario(scenario)
    route = [0, 1, 2]
    load = load_for_route(sim, route)
    nodes = [sim.start_node, *route, sim.landing_node]
    legs_s = sum(float(sim.legs.duration_s[a, b]) for a, b in zip(nodes[:-1], nodes[1:]))
    assert load.duration_s == pytest.approx(legs_s, rel=1e-6)
    ps = sim.params
    st = sim.initial
    pred = predict(ps, st.pack_state, np.tile(np.eye(4) * 1e-9, (4, 1, 1)), st.motor_temp_c, np.zeros(2), load,
                   rng=np.random.default_rng(0), n_samples=4, param_rel_sigma=0.0,
                   fault=np.asarray(sim._fault[0]), limits=scenario.limits.kernel_limits())
    ref = topology.simulate_powertrain(ps.pack_matrix()[None], ps.motor_vector()[None], st.pack_state[None],
                                     np.asarray(st.motor_temp_c)[None], load.dt, load.shaft_power_w, load.ambient_c,
                                     sim._fault, limits=scenario.limits.kernel_limits().as_tuple(), stop_on_failure=True)
    assert pred.p_failure == float(ref.failed[0])
    assert pred.peak_motor_temp_c[:, 1] == pytest.approx(ref.max_motor_temp[0], abs=1e-6)


def test_median_over_samples_is_numpys_nanmedian():
    """The compiled median of the trajectories equals ``np.nanmedian(axis=0)`` bit for bit: stopped
    samples (NaN) left out, even counts averaged, NaN where every sample stopped."""
    import warnings

    from gcs_pdm.estimation.prediction import _median_over_samples
    rng = np.random.default_rng(2)
    a = rng.normal(20.0, 3.0, (40, 30, 4))
    a[rng.random(a.shape) < 0.3] = np.nan
    a[:, 4] = np.nan
    a[:20, 6, 1] = np.nan          # an even count left
    a[:5, 7, 2] = np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        want = np.nanmedian(a, axis=0)
    got = _median_over_samples(a)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got[4]).all() and np.isfinite(got[6]).all()


def test_nearest_quantiles_and_motor_types_are_numpys():
    """The prediction's shortcuts give numpy's values: the quantiles (one sort, NaN columns NaN,
    infinities where they fall) and the motor types (one row when every motor's is the same)."""
    from gcs_pdm.estimation.prediction import QUANTILES, _motor_types, nearest_quantiles

    rng = np.random.default_rng(5)
    for n in (1, 2, 7, 99, 100, 101):
        a = rng.normal(size=(n, 4))
        a[rng.random(a.shape) < 0.2] = np.inf
        a[rng.random(a.shape) < 0.1] = -np.inf
        a[rng.random(a.shape) < 0.05] = np.nan
        want = np.quantile(a, QUANTILES, axis=0, method="nearest").T
        assert np.array_equal(nearest_quantiles(a), want, equal_nan=True), n
    motor = rng.normal(size=(1, 5))
    for rows in (np.broadcast_to(motor, (2, 5)), np.vstack([motor, motor * 1.1]), np.vstack([motor * 1.1, motor])):
        types, which = _motor_types(rows)
        want_types, want_which = np.unique(rows, axis=0, return_inverse=True)
        assert np.array_equal(types, want_types) and np.array_equal(np.ravel(which), np.ravel(want_which))
