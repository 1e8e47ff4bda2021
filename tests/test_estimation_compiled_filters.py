"""The compiled filter steps (``ukf.pack_step_rows`` / ``motor_step_rows``) against the batched
numpy formulation they replaced (sigma points, ``kernel.simulate_packs``, recombination, gated
Joseph updates, re-lock), step by step over random frames including gated spikes and re-locks.
Tolerance: 1e-9 relative — the two differ only in summation order."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.estimation import ukf
from gcs_pdm.estimation.motor_filter import MotorThermalFilter
from gcs_pdm.estimation.pack_filter import PackFilterBank
from gcs_pdm.models import kernel
from gcs_pdm.models.params import default_set


def numpy_pack_step(bank, idx, dt, current, ambient, voltage, temperature):
    """The numpy pack step as it was before it was compiled (issue 18)."""
    m = idx.size
    mean, cov = bank.mean[idx], bank.cov[idx]
    if np.any(dt > 0):
        pts = ukf.sigma_points(mean, cov)
        n_sig = pts.shape[1]
        rows = np.repeat(bank.params[idx], n_sig, axis=0)
        run = kernel.simulate_packs(rows, pts.reshape(m * n_sig, 4), np.repeat(dt, n_sig)[:, None],
                                    np.repeat(current, n_sig)[:, None], float(ambient))
        pmean, pcov = ukf.recombine(run.final_state.reshape(m, n_sig, 4))
        still = dt <= 0
        pmean[still], pcov[still] = mean[still], cov[still]
        mean, cov = pmean, pcov + bank._q[None] * np.maximum(dt, 0.0)[:, None, None]
    c = bank.config
    for ch, z, h, r in ((0, voltage, bank._h_v[idx], c.voltage_sigma_v ** 2),
                        (1, temperature, np.tile([0.0, 0, 0, 1], (m, 1)), c.temperature_sigma_c ** 2)):
        have = np.isfinite(z)
        if not have.any():
            continue
        sel = np.flatnonzero(have)
        nm, nc, nu, norm = ukf.scalar_update(mean[sel], cov[sel], h[sel], z[sel], r, c.gate)
        mean[sel], cov[sel] = nm, nc
        rows_idx = idx[sel]
        bank.last_innovation[rows_idx, ch] = nu
        gated = np.abs(norm) > c.gate
        bank.rejected_total[rows_idx[gated], ch] += 1
        bank.rejected_in_row[rows_idx, ch] = np.where(gated, bank.rejected_in_row[rows_idx, ch] + 1, 0)
        relock = bank.rejected_in_row[rows_idx, ch] >= c.relock_after
        if relock.any():
            k = sel[relock]
            cov[k] *= c.relock_inflation
            rm, rc, _, _ = ukf.scalar_update(mean[k], cov[k], h[k], z[k], r, np.inf)
            mean[k], cov[k] = rm, rc
            bank.relocks[rows_idx[relock]] += 1
            bank.rejected_in_row[rows_idx[relock], ch] = 0
    bank.mean[idx], bank.cov[idx] = mean, cov


def _banks():
    ps = default_set()
    a, b = PackFilterBank(ps.pack_matrix()), PackFilterBank(ps.pack_matrix())
    for bank in (a, b):
        bank.initialise(np.arange(4), np.array([20.5, 20.3, 20.6, 20.1]), np.full(4, 8.0), np.full(4, 21.0))
    return a, b


@pytest.mark.slow
def test_compiled_pack_step_matches_the_numpy_step_over_a_flight_with_spikes_and_relocks():
    compiled, reference = _banks()
    rng = np.random.default_rng(3)
    for k in range(600):
        idx = np.sort(rng.choice(4, size=rng.integers(1, 5), replace=False))
        dt = rng.choice([0.0, 0.5, 1.0, 45.0], size=idx.size, p=[0.05, 0.6, 0.3, 0.05])
        cur = rng.uniform(0.0, 25.0, idx.size)
        v = compiled.voltage()[0][idx] + rng.normal(0, 0.05, idx.size)
        v[rng.random(idx.size) < 0.1] = np.nan
        if 200 <= k < 215:
            v = v + 3.0  # a jump the model did not see: gated, then re-locked
        temp = np.where(rng.random(idx.size) < 0.5, 21.0 + rng.normal(0, 0.5, idx.size), np.nan)
        compiled.step(idx, dt, cur, 20.0, v, temp)
        numpy_pack_step(reference, idx, dt, cur, 20.0, v, temp)
    np.testing.assert_allclose(compiled.mean, reference.mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(compiled.cov, reference.cov, rtol=1e-7, atol=1e-9)
    assert compiled.relocks.sum() > 0 and compiled.rejected_total.sum() > 0
    np.testing.assert_array_equal(compiled.relocks, reference.relocks)
    np.testing.assert_array_equal(compiled.rejected_total, reference.rejected_total)
    np.testing.assert_allclose(compiled.last_innovation, reference.last_innovation, rtol=1e-7, atol=1e-9)


def test_compiled_motor_step_matches_the_unscented_step():
    ps = default_set()
    f = MotorThermalFilter(ps.motor_vector(), 2)
    f.initialise(np.arange(2), np.array([20.0, 22.0]), 2.0)
    mean, cov = f.mean.copy(), f.cov.copy()
    f.step(np.arange(2), np.array([1.0, 2.0]), np.array([10.0, 30.0]), 20.0, np.array([np.nan, 22.5]))
    pts = ukf.sigma_points(mean, cov)
    out = kernel.simulate_motor_thermal(np.repeat(f.params, 2, axis=0), pts.reshape(-1), np.array([[1.0], [1.0], [2.0], [2.0]]),
                                        np.array([[10.0], [10.0], [30.0], [30.0]]), 20.0)
    pm, pc = ukf.recombine(out[:, -1].reshape(2, 2, 1))
    pc = pc + f.config.process_sigma_c ** 2 * np.array([1.0, 2.0])[:, None, None]
    assert np.isclose(f.mean[0, 0], pm[0, 0], rtol=1e-12) and np.isclose(f.cov[0, 0, 0], pc[0, 0, 0], rtol=1e-12)
    nm, nc, _, _ = ukf.scalar_update(pm[1:], pc[1:], np.ones((1, 1)), np.array([22.5]), f.config.temperature_sigma_c ** 2, 5.0)
    assert np.isclose(f.mean[1, 0], nm[0, 0], rtol=1e-12) and np.isclose(f.cov[1, 0, 0], nc[0, 0, 0], rtol=1e-12)
