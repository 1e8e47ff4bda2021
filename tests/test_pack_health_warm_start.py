"""Pack-health checks start from the previous check's fit (issue 18): the warm fit must read the
pack as the cold multi-start search does, and the cold search must come back where a warm start
does not apply (a restarted record) or would change a verdict."""
import dataclasses

import numpy as np
import pytest

from gcs_pdm.diagnosis.faults import PACK_RESISTANCE_RISE
from gcs_pdm.diagnosis.pack_health import PackHealthConfig, PackHealthMonitor, fit_pack_residual
from gcs_pdm.models import kernel
from gcs_pdm.models.params import default_set

DT = 0.5


def pack_record(r_scale: float, seconds: float, seed: int = 3, b: int = 0, max_a: float = 30.0):
    """A pack flown through the kernel with its resistance scaled by ``r_scale``: current steps every
    20 s, 5 mV voltage noise."""
    params = default_set().pack_matrix()
    rng = np.random.default_rng(seed)
    n = int(seconds / DT)
    t = np.arange(n) * DT
    current = np.repeat(rng.uniform(4.0, max_a, n // 40 + 1), 40)[:n]
    ambient = np.full(n, 20.0)
    p = params[b].copy()
    p[kernel.I_RS] *= r_scale
    p[kernel.I_RCP0] *= r_scale
    x0 = kernel.initial_pack_state(p[None], np.array([1.0]), 20.0, float(current[0]))
    run = kernel.simulate_packs(p[None], x0, np.full(n, DT), current, ambient)
    voltage = run.voltage[0] + rng.normal(0.0, 0.005, n)
    return params, t, current, voltage, ambient


def fly(monitor: PackHealthMonitor, t, current, voltage, ambient, offset_s: float = 0.0, b: int = 0):
    """Feed one pack's record, checking as the pipeline does; (check time, estimate, fit counts) per check."""
    seen = []
    for k in range(t.size):
        now = float(t[k]) + offset_s
        monitor.add(b, now, float(current[k]), float(voltage[k]), float(ambient[k]))
        before = dict(monitor.fit_counts)
        monitor.check(now)
        if monitor.fit_counts != before:
            seen.append((now, monitor.latest[monitor.names[b]], dict(monitor.fit_counts)))
    return seen


def test_warm_checks_read_the_pack_as_the_cold_search_does():
    params, t, current, voltage, ambient = pack_record(1.4, 1500.0)
    mon = PackHealthMonitor(params, PackHealthConfig(cold_every_checks=1000))
    seen = fly(mon, t, current, voltage, ambient)
    assert mon.fit_counts["warm"] >= 10 and mon.fit_counts["warm"] > 3 * mon.fit_counts["cold"], mon.fit_counts
    # every warm estimate against the cold search on the same record (the newest max_samples)
    for now, est, _ in seen:
        keep = t <= now
        lo = max(int(np.sum(keep)) - mon.config.max_samples, 0)
        sl = slice(lo, int(np.sum(keep)))
        drawn = float(np.sum(current[sl][1:] * np.diff(t[sl]))) / params[0, kernel.I_CMAX]
        cold = fit_pack_residual(params[0], t[sl], current[sl], voltage[sl], ambient[sl],
                                 fit_capacity=drawn >= mon.config.min_drawn_for_capacity)
        theta, se, rms, _ = cold
        assert est.resistance_rise == pytest.approx(theta[0] - 1.0, abs=max(0.25 * se[0], 0.01)), now
        if np.isfinite(se[1]):
            assert est.capacity_factor == pytest.approx(theta[1], abs=max(0.25 * se[1], 0.01)), now
        assert est.residual_rms_v <= 1.05 * rms, now
    assert seen[-1][1].resistance_rise == pytest.approx(0.4, abs=0.05)


def test_a_restarted_record_is_fitted_cold():
    params, t, current, voltage, ambient = pack_record(1.0, 600.0)
    mon = PackHealthMonitor(params)
    fly(mon, t, current, voltage, ambient)
    assert mon.fit_counts["warm"] > 0
    cold_before = mon.fit_counts["cold"]
    # the same pack again after a 5-minute gap: the record restarts, and its first check is cold
    seen = fly(mon, t, current, voltage, ambient, offset_s=float(t[-1]) + 300.0)
    assert seen[0][2]["cold"] == cold_before + 1 and seen[0][2]["warm_rejected"] == 0


def test_a_warm_fit_that_would_change_a_verdict_is_redone_cold():
    # a pack whose resistance rises slowly past the raise threshold (the residual of each warm fit
    # stays small): the verdict changes (not strong -> strong), and that check's fit is the cold search's
    params, t, current, v_weak, ambient = pack_record(2.5, 1200.0, max_a=15.0)
    _, _, _, v_healthy, _ = pack_record(1.0, 1200.0, max_a=15.0)
    voltage = v_healthy + (v_weak - v_healthy) * np.clip(t / 900.0, 0.0, 1.0)
    mon = PackHealthMonitor(params, PackHealthConfig(cold_every_checks=1000, max_samples=600))
    fly(mon, t, current, voltage, ambient)
    assert mon.fit_counts["warm_unconfirmed"] >= 1 and mon.fit_counts["warm"] >= 3, mon.fit_counts
    fault = mon.faults[(PACK_RESISTANCE_RISE, mon.names[0])]
    assert fault.active and fault.magnitude == pytest.approx(1.5, abs=0.2)


def test_warm_start_can_be_turned_off():
    params, t, current, voltage, ambient = pack_record(1.0, 600.0)
    mon = PackHealthMonitor(params, dataclasses.replace(PackHealthConfig(), warm_start=False))
    fly(mon, t, current, voltage, ambient)
    assert mon.fit_counts["warm"] == 0 and mon.fit_counts["cold"] > 3
