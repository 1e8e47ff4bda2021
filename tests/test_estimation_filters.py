"""State estimator: UKF helpers, pack and motor filters, robustness to spikes, gaps, disorder."""
import numpy as np
import pytest

from gcs_pdm.estimation import ukf
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.synthetic import SensorNoise, fly_synthetic
from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.models.params import default_set
from gcs_pdm.sim.truth import true_parameters


def run(flight, params, every=None):
    est = StateEstimator(params)
    trace = []
    for fr in flight.frames:
        est.consume(fr)
        if every is not None and est.ready():
            trace.append((est.time_s, est.estimate()))
    return est, trace


def truth_at(flight, t):
    return min(int(np.searchsorted(flight.time_s, t)), flight.time_s.size - 1)


def test_sigma_points_reproduce_mean_and_covariance():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 4, 4))
    cov = a @ a.transpose(0, 2, 1) + np.eye(4)
    mean = rng.normal(size=(3, 4))
    m, c = ukf.recombine(ukf.sigma_points(mean, cov))
    assert np.allclose(m, mean) and np.allclose(c, cov)


def test_scalar_update_is_the_kalman_update_and_gates():
    mean = np.array([[1.0, 2.0]])
    cov = np.array([[[2.0, 0.5], [0.5, 1.0]]])
    h = np.array([[1.0, -1.0]])
    m, c, nu, norm = ukf.scalar_update(mean, cov, h, np.array([0.5]), 0.1, gate=10.0)
    s = h[0] @ cov[0] @ h[0] + 0.1
    k = cov[0] @ h[0] / s
    assert np.allclose(m[0], mean[0] + k * (0.5 - h[0] @ mean[0]))
    assert np.allclose(c[0], cov[0] - np.outer(k, k) * s)
    m2, c2, _, norm2 = ukf.scalar_update(mean, cov, h, np.array([100.0]), 0.1, gate=5.0)
    assert abs(norm2[0]) > 5 and np.array_equal(m2, mean) and np.allclose(c2, cov)


@pytest.fixture(scope="module")
def known_flight():
    ps = default_set()
    return ps, fly_synthetic(ps, np.random.default_rng(11), duration_s=600.0, initial_soc=0.9)


def test_soc_tracks_truth_with_known_parameters(known_flight):
    ps, flight = known_flight
    est, _ = run(flight, ps)
    e = est.estimate()
    k = truth_at(flight, e.time_s)
    err = e.soc - flight.soc[k]
    # started from voltage alone (true SoC 0.9, not announced): converges to the percent level
    assert np.all(np.abs(err) < 0.02), err
    assert np.all(np.abs(err) < 3 * e.soc_sd)
    assert np.all(np.abs(e.pack_temp_c - flight.pack_temp_c[k]) < 1.0)
    assert np.all(np.abs(e.motor_temp_c - flight.motor_temp_c[k]) < 1.0)
    assert e.counters["voltage_gated"] > 0  # the flight's spikes were seen and refused
    assert e.missing == ()


def test_soc_uncertainty_is_honest_with_unknown_parameters():
    truth = true_parameters()
    flight = fly_synthetic(truth, np.random.default_rng(5), duration_s=900.0)
    est, _ = run(flight, default_set())
    e = est.estimate()
    k = truth_at(flight, e.time_s)
    err = e.soc - flight.soc[k]
    assert np.all(np.abs(err) < 3 * e.soc_sd), (err, e.soc_sd)
    assert np.all(np.abs(err) < 0.1)


def test_gap_keeps_running_reports_missing_and_recovers(known_flight):
    ps, flight = known_flight
    gap = (200.0, 260.0)
    frames = [f for f in flight.frames if not (isinstance(f, PackFrame) and gap[0] < f.time_s < gap[1])]
    est = StateEstimator(ps)
    sd_before = sd_during = None
    missing_during = ()
    for fr in frames:
        est.consume(fr)
        if sd_before is None and fr.time_s >= gap[0]:
            sd_before = est.estimate().soc_sd.copy()
        if fr.time_s >= gap[1] - 1 and not missing_during:
            missing_during = est.missing()
    assert "LLF20.voltage" in missing_during and "fwd.current" not in missing_during
    e = est.estimate()
    k = truth_at(flight, e.time_s)
    assert np.all(np.abs(e.soc - flight.soc[k]) < 0.02)


def test_spikes_out_of_order_and_unknown_are_counted_not_fatal(known_flight):
    ps, flight = known_flight
    est = StateEstimator(ps)
    frames = flight.frames[:2000]
    for fr in frames:
        est.consume(fr)
    before = est.estimate()
    t = est.time_s
    est.consume(PackFrame(t + 0.5, "LLF20", 35.0, 12.0, 25.0))     # a wild voltage
    est.consume(PackFrame(t - 10.0, "ULA20", 20.0, 12.0, 25.0))    # from the past
    est.consume(PackFrame(t + 0.5, "NOPE", 20.0, 12.0, 25.0))
    est.consume(MotorFrame(t + 0.5, "fwd", None, None, None))       # all values missing
    after = est.estimate()
    assert after.counters["voltage_gated"] == before.counters["voltage_gated"] + 1
    assert after.counters["out_of_order"] == 1 and after.counters["unknown_pack"] == 1
    assert abs(after.soc[0] - before.soc[0]) < 0.002


def test_current_spike_is_replaced_by_the_string_reading(known_flight):
    ps, flight = known_flight
    est = StateEstimator(ps)
    for fr in flight.frames[:2000]:
        est.consume(fr)
    t = est.time_s + 0.5
    est.consume(MotorFrame(t, "fwd", 12.0, 4000.0, 30.0))
    est.consume(PackFrame(t, "LRF40", 20.0, 12.0, 25.0))
    n0 = est.counters["current_spikes"]
    est.consume(PackFrame(t + 0.1, "LLF20", 20.0, 400.0, 25.0))
    assert est.counters["current_spikes"] == n0 + 1
    assert est.pack_current[0] == pytest.approx(12.0)


def test_uneven_and_sparse_sampling_still_tracks():
    ps = default_set()
    flight = fly_synthetic(ps, np.random.default_rng(3), duration_s=600.0, step_s=1.5, pack_every=3,
                           noise=SensorNoise(drop_rate=0.2))
    est, _ = run(flight, ps)
    e = est.estimate()
    k = truth_at(flight, e.time_s)
    assert np.all(np.abs(e.soc - flight.soc[k]) < 0.03)
    assert np.all(np.abs(e.motor_temp_c - flight.motor_temp_c[k]) < 1.5)
