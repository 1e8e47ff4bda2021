"""A warm pack-health check carries the previous check's kernel run on over the new samples instead of
simulating the whole record again (issue 18): the run must continue exactly, the one step it takes
must read the pack as a fresh fit does, and a step beyond its Jacobian's range must fall back to
the fresh fit."""
import dataclasses

import numpy as np
import pytest

from gcs_pdm.diagnosis.pack_health import (_EPS, PackHealthConfig, PackHealthMonitor, _fit_extended,
                                           _gauss_newton)
from gcs_pdm.models import kernel
from test_pack_health_warm_start import fly, pack_record


def test_the_extension_continues_the_previous_run_exactly():
    params, t, current, voltage, ambient = pack_record(1.3, 900.0)
    p = params[0]
    first = slice(0, 1200)
    fit = _gauss_newton(p, t[first], np.diff(t[first], prepend=t[0]), current[first], voltage[first],
                        ambient[first], 0.2, 10, 1.0, 1.0, True)
    sim = fit[5]
    # the record slid by 120 samples and grew by 240
    later = slice(120, 1440)
    ext = _fit_extended(p, t[later], current[later], voltage[later], ambient[later], 0.2, t[first], sim)
    assert ext is not None
    # the same rows simulated in one run from the first record's start
    x0 = np.empty((sim.params.shape[0], kernel.N_PACK_STATE))
    for v in range(x0.shape[0]):
        soc = sim.theta[2] + (_EPS[2] if v > 0 and sim.perturbed[v - 1] == 2 else 0.0)
        x0[v] = kernel.initial_pack_state(sim.params[v:v + 1], np.array([soc]), float(ambient[0]),
                                          float(current[0]))[0]
    whole = kernel.simulate_packs(sim.params, x0, np.diff(t[:1440], prepend=t[0]), current[:1440], ambient[:1440])
    np.testing.assert_array_equal(ext[5].voltage, whole.voltage[:, 120:])
    np.testing.assert_array_equal(ext[5].soc, whole.soc[:, 120:])
    np.testing.assert_array_equal(ext[5].final, whole.final_state)
    # the step's theta is that of the run's start; the estimate's SoC is the record's first sample's
    assert ext[0][2] == pytest.approx(whole.soc[0, 120], abs=2e-3)


def test_extended_checks_read_the_pack_as_fresh_warm_fits_do():
    params, t, current, voltage, ambient = pack_record(1.4, 1500.0, seed=5)
    cfg = PackHealthConfig(cold_every_checks=1000)
    extended = fly(PackHealthMonitor(params, cfg), t, current, voltage, ambient)
    fresh_mon = PackHealthMonitor(params, dataclasses.replace(cfg, extend_fits=False))
    fresh = fly(fresh_mon, t, current, voltage, ambient)
    counts = extended[-1][2]
    assert counts["extended"] >= 10 and counts["warm"] >= counts["extended"], counts
    assert fresh_mon.fit_counts["extended"] == 0
    assert [now for now, *_ in extended] == [now for now, *_ in fresh]
    for (now, got, _), (_, want, _) in zip(extended, fresh):
        assert got.resistance_rise == pytest.approx(want.resistance_rise, abs=max(0.25 * want.se_resistance_rise, 0.01)), now
        if np.isfinite(want.se_capacity_loss):
            assert got.capacity_factor == pytest.approx(want.capacity_factor, abs=max(0.25 * want.se_capacity_loss, 0.01)), now
        assert got.initial_soc == pytest.approx(want.initial_soc, abs=0.01), now
        assert got.residual_rms_v <= 1.05 * want.residual_rms_v, now
        assert got.se_resistance_rise == pytest.approx(want.se_resistance_rise, rel=0.2), now
    assert extended[-1][1].resistance_rise == pytest.approx(0.4, abs=0.05)


def test_a_step_beyond_the_jacobians_range_is_fitted_afresh():
    # the pack's resistance doubles over 15 minutes: each check's step from the previous run leaves
    # the range its Jacobian was taken over, so the record is fitted afresh, and the checks read the
    # pack as the monitor without the extension does
    params, t, current, v_weak, ambient = pack_record(2.0, 1500.0, seed=7)
    _, _, _, v_healthy, _ = pack_record(1.0, 1500.0, seed=7)
    voltage = v_healthy + (v_weak - v_healthy) * np.clip((t - 300.0) / 900.0, 0.0, 1.0)
    cfg = PackHealthConfig(cold_every_checks=1000, max_samples=600)
    mon = PackHealthMonitor(params, cfg)
    seen = fly(mon, t, current, voltage, ambient)
    fresh = fly(PackHealthMonitor(params, dataclasses.replace(cfg, extend_fits=False)), t, current, voltage, ambient)
    counts = mon.fit_counts
    assert counts["warm"] - counts["extended"] >= 5 and counts["extended"] <= 2, counts
    for (now, got, _), (_, want, _) in zip(seen, fresh):
        assert got.resistance_rise == pytest.approx(want.resistance_rise, abs=max(0.25 * want.se_resistance_rise, 0.01)), now
    assert seen[-1][1].resistance_rise == pytest.approx(1.0, abs=0.15)


def test_a_jump_the_extension_fits_better_than_a_fresh_start():
    # the resistance doubles at once 10 minutes in. A fresh fit starts the record with the R–C pairs
    # settled at its first sample's current, which a record starting mid-flight does not have: its
    # first samples misfit, and the MAD cut takes some of them out. The extension carries the run's
    # own state, so it keeps those samples and reads the jump, and the SoC, as well.
    params, t, current, v_healthy, ambient = pack_record(1.0, 1500.0, seed=7)
    x0 = kernel.initial_pack_state(params[:1], np.array([1.0]), 20.0, float(current[0]))
    true_soc = kernel.simulate_packs(params[:1], x0, np.diff(t, prepend=t[0]), current, ambient).soc[0]
    _, _, _, v_weak, _ = pack_record(2.0, 1500.0, seed=7)
    voltage = np.where(t < 600.0, v_healthy, v_weak)
    cfg = PackHealthConfig(cold_every_checks=1000, max_samples=600)
    seen = fly(PackHealthMonitor(params, cfg), t, current, voltage, ambient)
    fresh = fly(PackHealthMonitor(params, dataclasses.replace(cfg, extend_fits=False)), t, current, voltage, ambient)
    after = [(now, got, want) for (now, got, _), (_, want, _) in zip(seen, fresh) if now >= 900.0]
    assert after and seen[-1][2]["extended"] >= 10
    for now, got, want in after:
        assert got.resistance_rise == pytest.approx(1.0, abs=0.01), now
        assert got.residual_rms_v <= want.residual_rms_v, now
        first = int(np.searchsorted(t, now, side="right")) - cfg.max_samples  # the record's first sample
        assert got.initial_soc == pytest.approx(true_soc[first], abs=0.003), now
