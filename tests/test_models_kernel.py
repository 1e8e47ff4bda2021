"""The simulation kernel against closed forms, and against itself (batching, step sizes)."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.models import kernel as K
from gcs_pdm.models.params import default_set, perturbed

PACK = default_set().pack_matrix()[0]


def _pack(**changes: float) -> np.ndarray:
    p = PACK.copy()
    for name, value in changes.items():
        p[K.PACK_PARAMS.index(name)] = value
    return p


def _even(n: int, step: float) -> np.ndarray:
    dt = np.full(n, step)
    dt[0] = 0.0
    return dt


def test_rest_only_self_discharges_through_R_p():
    # no load, no polarisation: q_b drains through R_p alone, q_b(t) = q_b0 exp(-t / (C_b R_p))
    p = _pack(R_cp1=0.0)
    x0 = K.initial_pack_state(p, 1.0, 20.0)
    n, step = 2000, 3600.0  # 83 days in hour steps
    out = K.simulate_packs(p, x0, _even(n, step), np.zeros(n), 20.0, record_states=True)
    t = np.arange(n) * step
    tau = p[K.I_CB] * p[K.I_RP]
    expected_qb = x0[0, K.S_QB] * np.exp(-t / tau)
    np.testing.assert_allclose(out.states[0, :, K.S_QB], expected_qb, rtol=2e-5)
    # and the pack really lost charge (about 3 % of q_max over this time)
    assert out.states[0, -1, K.S_QB] < 0.98 * x0[0, K.S_QB]
    # temperature stays at ambient with no current
    np.testing.assert_allclose(out.temperature, 20.0)


def test_constant_current_draws_integral_of_current():
    p = _pack()
    x0 = K.initial_pack_state(p, 1.0, 25.0)
    n, step, amps = 1801, 1.0, 18.0
    out = K.simulate_packs(p, x0, _even(n, step), np.full(n, amps), 25.0, record_states=True)
    drawn = x0[0, K.S_QB] - out.states[0, :, K.S_QB]
    t = np.arange(n) * step
    # the parasitic branch adds at most V_max / R_p amps on top of the load
    parasitic_bound = 21.0 / p[K.I_RP] * t
    assert np.all(np.abs(drawn - amps * t) <= parasitic_bound + 1e-9)
    np.testing.assert_allclose(out.soc[0], 1.0 - drawn / p[K.I_CMAX])


def test_voltage_relaxes_with_the_RC_time_constants():
    # R_p effectively infinite and R_cp independent of SoC: the circuit is linear, so the terminal
    # voltage after a current step has the closed form of two first-order lags on a ramp
    p = _pack(R_p=1e15, R_cp1=0.0)
    x0 = K.initial_pack_state(p, 1.0, 25.0)
    n, step, amps = 121, 0.25, 30.0
    out = K.simulate_packs(p, x0, _even(n, step), np.full(n, amps), 25.0)
    t = np.arange(n) * step
    r_s, c_s, r_cp, c_cp, c_b = (p[K.I_RS], p[K.I_CS], p[K.I_RCP0], p[K.I_CCP], p[K.I_CB])
    expected = (x0[0, K.S_QB] - amps * t) / c_b - amps * r_s * (1 - np.exp(-t / (r_s * c_s))) \
        - amps * r_cp * (1 - np.exp(-t / (r_cp * c_cp)))
    np.testing.assert_allclose(out.voltage[0], expected, atol=1e-9)
    # time constants of the order of seconds, as the design asks
    assert 0.3 < r_s * c_s < 5 and 2 < r_cp * c_cp < 60


def test_pack_thermal_step_matches_analytic_exponential():
    p = _pack(R_p=1e15, R_cp1=0.0)
    x0 = K.initial_pack_state(p, 1.0, 10.0, current=20.0)  # R–C pairs already settled
    n, step, amps, ambient = 400, 5.0, 20.0, 15.0
    out = K.simulate_packs(p, x0, _even(n, step), np.full(n, amps), ambient)
    t = np.arange(n) * step
    heat = (p[K.I_RS] + p[K.I_RCP0]) * amps**2
    t_inf = ambient + heat / p[K.I_H]
    expected = t_inf + (10.0 - t_inf) * np.exp(-t * p[K.I_H] / p[K.I_CT])
    np.testing.assert_allclose(out.temperature[0], expected, atol=1e-9)


def test_motor_thermal_step_matches_analytic_exponential():
    m = default_set().motor_vector()
    n, step, amps, ambient, t0 = 300, 2.0, 25.0, 18.0, 30.0
    temp = K.simulate_motor_thermal(m, t0, _even(n, step), np.full(n, amps), ambient)
    t = np.arange(n) * step
    heat = m[K.M_RW] * amps**2 + m[K.M_PIRON]
    t_inf = ambient + heat / m[K.M_H]
    np.testing.assert_allclose(temp[0], t_inf + (t0 - t_inf) * np.exp(-t * m[K.M_H] / m[K.M_CT]), atol=1e-9)


def _profile(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    dt = rng.uniform(0.5, 2.0, n)
    dt[0] = 0.0
    current = np.clip(15 + 10 * np.sin(np.arange(n) / 60) + rng.normal(0, 3, n), 0, None)
    ambient = 20 + rng.normal(0, 0.5, n)
    return dt, current, ambient


def test_batched_equals_one_vector_at_a_time():
    rng = np.random.default_rng(1)
    base = default_set()
    params = np.stack([perturbed(base, rng, 0.2).pack_matrix()[i % 4] for i in range(7)])
    x0 = K.initial_pack_state(params, rng.uniform(0.3, 1.0, 7), rng.uniform(10, 30, 7))
    dt, current, ambient = _profile(rng, 500)
    per_vector_current = current[None, :] * rng.uniform(0.5, 1.5, (7, 1))
    batched = K.simulate_packs(params, x0, dt, per_vector_current, ambient, record_states=True)
    for j in range(7):
        single = K.simulate_packs(params[j], x0[j], dt, per_vector_current[j], ambient, record_states=True)
        np.testing.assert_array_equal(batched.voltage[j], single.voltage[0])
        np.testing.assert_array_equal(batched.temperature[j], single.temperature[0])
        np.testing.assert_array_equal(batched.states[j], single.states[0])
        np.testing.assert_array_equal(batched.final_state[j], single.final_state[0])


def test_step_size_refinement_converges_near_the_knee():
    # near empty, R_cp(SoC) changes fast, so freezing it over a step is where the error lives
    p = _pack()
    x0 = K.initial_pack_state(p, 0.12, 25.0)
    horizon, amps = 240.0, 12.0  # discharges to about 2 % SoC
    results = {}
    for step in (20.0, 10.0, 5.0, 2.5, 1.25, 0.3125):
        n = int(horizon / step) + 1
        out = K.simulate_packs(p, x0, _even(n, step), np.full(n, amps), 25.0, max_dt=1e9)
        results[step] = out.voltage[0, -1]
    reference = results[0.3125]
    errors = [abs(results[s] - reference) for s in (20.0, 10.0, 5.0, 2.5, 1.25)]
    assert all(a > b for a, b in zip(errors, errors[1:])), errors
    assert errors[0] > 1e-5  # the test would be vacuous if the knee did not matter
    # second order (R_cp taken at the mid-step charge): halving the step quarters the error
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 3.0) & (ratios < 5.0)), ratios
    # and max_dt sub-stepping buys the accuracy of the fine step at coarse sample times
    n = int(horizon / 20.0) + 1
    sub = K.simulate_packs(p, x0, _even(n, 20.0), np.full(n, amps), 25.0, max_dt=1.25)
    assert abs(sub.voltage[0, -1] - reference) <= errors[-1] * 1.01


def test_uneven_steps_equal_the_profile_resampled_evenly():
    rng = np.random.default_rng(7)
    # uneven sample times on a 0.5 s grid, including a 20 s drop-out
    gaps = rng.choice([0.5, 1.0, 1.5, 3.0], size=300)
    gaps[150] = 20.0
    t = np.concatenate([[0.0], np.cumsum(gaps)])
    current = rng.uniform(5, 40, t.size)
    ambient = 18.0
    p = default_set().pack_matrix()[2]
    x0 = K.initial_pack_state(p, 0.9, 22.0)
    uneven = K.simulate_packs(p, x0, np.diff(t, prepend=0.0), current, ambient)
    # the same profile on an even 0.5 s grid: each fine step carries the current of the interval
    # (t_{k-1}, t_k] it falls into
    fine_t = np.arange(0.0, t[-1] + 0.25, 0.5)
    owner = np.searchsorted(t, fine_t, side="left")
    even = K.simulate_packs(p, x0, _even(fine_t.size, 0.5), current[owner], ambient)
    at = np.searchsorted(fine_t, t)
    np.testing.assert_allclose(fine_t[at], t)
    np.testing.assert_allclose(uneven.voltage[0], even.voltage[0, at], atol=2e-4)
    np.testing.assert_allclose(uneven.temperature[0], even.temperature[0, at], atol=1e-6)


def test_inputs_are_checked():
    p = default_set().pack_matrix()[0]
    x0 = K.initial_pack_state(p, 1.0, 20.0)
    with pytest.raises(ValueError, match="dt"):
        K.simulate_packs(p, x0, np.array([0.0, -1.0]), np.ones(2), 20.0)
    with pytest.raises(ValueError, match="current"):
        K.simulate_packs(np.stack([p, p]), np.stack([x0[0], x0[0]]), np.ones(3), np.ones((3, 3)), 20.0)
    with pytest.raises(ValueError, match="params"):
        K.simulate_packs(p[:5], x0, np.ones(3), np.ones(3), 20.0)


@pytest.mark.parametrize("parallel", [False, True])
def test_blocks_of_lanes_equal_one_vector_at_a_time_on_awkward_intervals(parallel):
    """The block driver steps LANES vectors together and reuses each interval's decay factors; a
    batch that is not a multiple of LANES, per-vector intervals that differ (zero, sub-stepped gaps,
    a repeated length), a NaN interval and a NaN state must still give each vector's own run, bit for bit."""
    rng = np.random.default_rng(4)
    base = default_set()
    n_vec = K.LANES + 5
    params = np.stack([perturbed(base, rng, 0.2).pack_matrix()[i % 4] for i in range(n_vec)])
    x0 = K.initial_pack_state(params, rng.uniform(0.3, 1.0, n_vec), 20.0)
    x0[3, K.S_QS] = np.nan
    n = 400
    dt = np.abs(1.0 + rng.normal(0, 0.05, (n_vec, n)))
    dt[:, 0] = 0.0
    dt[::2, 50] = 0.0                   # some lanes rest while others step
    dt[1::3, 120] = 95.0                # and some cut their interval into sub-steps
    dt[:, 200:260] = 0.5                # a run of equal steps (the cached factors)
    dt[5, 300] = np.nan
    current = np.clip(15 + 10 * np.sin(np.arange(n) / 30) + rng.normal(0, 3, (n_vec, n)), 0, None)
    batched = K.simulate_packs(params, x0, dt, current, 20.0, record_states=True, parallel=parallel)
    for j in range(n_vec):
        single = K.simulate_packs(params[j], x0[j], dt[j], current[j], 20.0, record_states=True)
        for name in ("voltage", "temperature", "soc", "states", "final_state"):
            np.testing.assert_array_equal(getattr(batched, name)[j], getattr(single, name)[0], err_msg=f"{name}[{j}]")
    assert np.isnan(batched.voltage[3]).all() and np.isnan(batched.voltage[5, 300:]).all()
    assert np.isfinite(batched.voltage[4]).all()


def test_pack_advance_is_the_block_drivers_step():
    """``_pack_advance`` (one row, as the estimator's sigma points use it) and the batch driver agree bit for bit."""
    rng = np.random.default_rng(6)
    p = default_set().pack_matrix()[2]
    x = K.initial_pack_state(p, 0.8, 22.0)[0]
    dt = np.array([0.0, 1.0, 1.0, 0.5, 37.0, 1.0])
    current = rng.uniform(5, 30, dt.size)
    run = K.simulate_packs(p, x, dt, current, 18.0, record_states=True)
    for k in range(dt.size):
        K._pack_advance(p, x, current[k], 18.0, dt[k], K.DEFAULT_MAX_DT)
        np.testing.assert_array_equal(x, run.states[0, k])
