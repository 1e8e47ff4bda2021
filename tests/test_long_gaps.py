"""Work bounded by samples, not by the time span (issue 18, found by the link-safety work): a
49.7-day gap in a log (a 32-bit millisecond clock wrapping) must not cost the kernel a sub-step per
10 s, nor sit in the pack-health record to be re-simulated at every check; the estimator restarts
a filter after a gap its held current cannot describe."""
from __future__ import annotations

import math

import numpy as np

from gcs_pdm.diagnosis.pack_health import PackHealthConfig, PackHealthMonitor
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES, default_set

GAP_S = 2 ** 32 / 1000.0  # 49.7 days


def _run(dt: np.ndarray, current: float = 0.0, max_dt: float = kernel.DEFAULT_MAX_DT) -> np.ndarray:
    p = default_set().pack_matrix()[:1]
    x0 = kernel.initial_pack_state(p, 0.9, 20.0, current)
    return kernel.simulate_packs(p, x0, dt, np.full(dt.size, current), 20.0, max_dt=max_dt).final_state[0]


def test_kernel_sub_steps_of_a_long_gap_are_capped():
    # a 49.7-day interval is integrated in MAX_SUBSTEPS equal sub-steps: exactly what stepping it
    # in that many explicit samples gives (not the 429,497 sub-steps of 10 s it used to take)
    # (at rest, the gap's physics: the parasitic branch drains it; 10 s sub-steps differ by ~1e-7)
    n = kernel.MAX_SUBSTEPS
    capped = _run(np.array([GAP_S]))
    assert np.all(np.isfinite(capped))
    np.testing.assert_allclose(capped, _run(np.full(n, GAP_S / n), 0.0, GAP_S / n), rtol=1e-12, atol=0.0)


def test_extended_variant_sub_steps_of_a_long_gap_are_capped_too():
    # a 10 h gap at 0.1 A: capped, it is MAX_SUBSTEPS sub-steps of 100 s, exactly what that many
    # explicit samples give; uncapped (3600 sub-steps of 10 s) the first R-C voltage differs by ~1e-7
    from gcs_pdm.models.params import extended_default

    p = np.array([[extended_default()[k] for k in kernel.EXT_PACK_PARAMS]])
    x0 = kernel.initial_extended_state(p, 0.9, 20.0, 0.1)

    def run(dt, max_dt):
        return kernel.simulate_packs(p, x0, dt, np.full(dt.size, 0.1), 20.0, max_dt=max_dt,
                                     variant="extended").final_state[0]

    n = kernel.MAX_SUBSTEPS
    gap = 10 * n * kernel.DEFAULT_MAX_DT
    np.testing.assert_allclose(run(np.array([gap]), kernel.DEFAULT_MAX_DT), run(np.full(n, gap / n), gap / n),
                               rtol=1e-10, atol=0.0)
    assert np.all(np.isfinite(run(np.array([GAP_S]), kernel.DEFAULT_MAX_DT)))


def test_kernel_gaps_under_the_cap_integrate_as_before():
    dt = 0.5 * kernel.MAX_SUBSTEPS * kernel.DEFAULT_MAX_DT + 3.0  # ceil(dt / max_dt) sub-steps, uncapped
    n = math.ceil(dt / kernel.DEFAULT_MAX_DT)
    np.testing.assert_allclose(_run(np.array([dt]), 5.0), _run(np.full(n, dt / n), 5.0, dt / n), rtol=1e-12, atol=0.0)


def test_pack_health_record_is_bounded_and_restarts_after_a_long_gap():
    cfg = PackHealthConfig(max_samples=500)
    mon = PackHealthMonitor(default_set().pack_matrix(), cfg)
    for k in range(2000):
        mon.add(0, float(k), 10.0, 20.0, 20.0)
    assert len(mon._buf[0]) == 500 and mon._buf[0][0][0] == 1500.0
    mon.add(0, 1999.0 + GAP_S, 10.0, 20.0, 20.0)
    assert [s[0] for s in mon._buf[0]] == [1999.0 + GAP_S]
    # a gap under max_gap_s (a short link outage) keeps the record
    mon.add(0, 1999.0 + GAP_S + cfg.max_gap_s, 10.0, 20.0, 20.0)
    assert len(mon._buf[0]) == 2


def test_estimator_restarts_a_pack_and_a_motor_after_a_long_gap():
    est = StateEstimator(default_set())
    for t in np.arange(0.0, 60.0, 1.0):
        for i, name in enumerate(PACK_NAMES):
            est.consume(PackFrame(time_s=t, pack=name, voltage_v=20.4, current_a=10.0, temperature_c=25.0))
        est.consume(MotorFrame(time_s=t, motor="fwd", current_a=10.0, rpm=2000.0, temperature_c=30.0))
    before = est.estimate().soc[0]
    t = 59.0 + GAP_S
    # after the gap the pack rested: a higher voltage and no current. The filter starts from that
    # reading rather than integrating 10 A over 49.7 days (which would empty the pack many times)
    est.consume(PackFrame(time_s=t, pack=PACK_NAMES[0], voltage_v=21.0, current_a=0.0, temperature_c=18.0))
    est.consume(MotorFrame(time_s=t, motor="fwd", current_a=0.0, rpm=0.0, temperature_c=18.0))
    e = est.estimate()
    assert e.counters["restarts"] == 2
    assert 0.0 <= e.soc[0] <= 1.0 and e.soc[0] > before
    assert e.pack_temp_c[0] == 18.0 and e.motor_temp_c[0] == 18.0

