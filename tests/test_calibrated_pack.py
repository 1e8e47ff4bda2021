"""Issue 32 item 2: a self-calibrated pack's learned model as the kernel's extended pack
(``estimation.calibrated_pack``), flown by the route risk and the prediction instead of the
description's kernel pack with only the calibrated SoC."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from gcs_pdm.estimation.calibrated_pack import CalibratedCircuit, CalibratedPacks
from gcs_pdm.estimation.calibration import TAU2_FACTOR, _measurement, _predict_core
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.models import kernel, topology
from gcs_pdm.replay.calibration_eval import simulated_case
from gcs_pdm.vehicle.model_inputs import model_inputs

STEPS = 2000


@pytest.fixture(scope="module")
def half_way():
    """A LiPo quad pack the service was never told about (truth 0.8x its label's capacity, 2x the
    resistance, on the chemistry's curve) flown at a held 1.5 C from 90 %, the estimator stopped
    half-way to the cut-off. (case, sample index of the stop, the pack's circuit)."""
    case = simulated_case("quad-4s", capacity_scale=0.8, resistance_scale=2.0, start_soc=0.9, seed=4,
                          duration_s=3000.0, c_rate=(1.5, 1.5), chemistry_curve=True)
    half = 30 + (case.end - 30) // 2
    for k in range(half):
        case.feed(k)
    cal = case.estimator.calib[0]
    return case, half - 1, CalibratedCircuit.of(cal, case.estimator.packs.params[0])


def _lead_filter(case):
    """The pack's filter the circuit was built from (a LiPo's curve bank: its leading curve's)."""
    cal = case.estimator.calib[0]
    return getattr(cal, "lead", cal)


def _kernel_flight(vectors: np.ndarray, states: np.ndarray, circuit: CalibratedCircuit, current: float,
                   temperature_c: float):
    """The kernel's extended step on ``vectors`` at a held current, from the calibrator's
    temperature on its own thermal model (the pack heats; its resistances stay the present's)."""
    n = vectors.shape[0]
    x0 = circuit.pack_states(states, temperature_c)
    return kernel.simulate_packs(vectors, x0, np.ones(STEPS), np.full((n, STEPS), current), np.full(STEPS, 25.0),
                                 variant="extended")


def test_the_kernel_flies_the_calibrators_model_on_its_mapped_pack(half_way):
    case, _, circuit = half_way
    cal, m = _lead_filter(case), circuit.model
    cutoff_v = case.description.packs[0].cutoff_voltage
    current = m.held_current(1.5 * cal.q0 / 3600.0)
    run = _kernel_flight(circuit.mean_vector()[None], m.x[None], circuit, current, cal.temp_c)
    # the filter's own model forward from its mean state, with the present shortfall the count-down keeps
    x, p = m.x.copy(), cal.P.copy()
    beyond = m.sag_beyond_model_ohm(m.x[None])[0] * current
    own_v, own_soc = np.empty(STEPS), np.empty(STEPS)
    unbounded = np.full(x.size, -np.inf), np.full(x.size, np.inf)  # the model itself, not the filter's bounds
    for k in range(STEPS):
        _predict_core(x, p, 1.0, current, m.temp_u, m.q0, circuit.tau1_s, TAU2_FACTOR * circuit.tau1_s, cal.r0p,
                      cal.r1p, 0.0, 0.0, *unbounded)
        own_v[k] = _measurement(x, m.table, m.cells, m.mid, current, m.temp_u, np.empty(x.size)) - beyond
        own_soc[k] = x[0]
    np.testing.assert_allclose(run.soc[0], own_soc, atol=1e-9)  # the learned capacity
    above = own_soc > 0.2  # below, the count-down's rise near empty takes over (the filter has none)
    assert above.sum() > 200
    rms = float(np.sqrt(np.mean((run.voltage[0, above] - own_v[above]) ** 2)))
    assert rms < 0.005, rms  # the curve (cubic through the kernel's knots), both pairs, R0 and E
    crossed = np.flatnonzero(run.voltage[0] < cutoff_v)
    assert crossed.size
    assert abs((crossed[0] + 1) / m.time_to_cutoff(current, cutoff_v) - 1.0) < 0.03


def test_each_draw_is_its_own_count_down(half_way):
    case, _, circuit = half_way
    cal, m = _lead_filter(case), circuit.model
    cutoff_v = case.description.packs[0].cutoff_voltage
    current = m.held_current(1.5 * cal.q0 / 3600.0)
    states = m.draw_states(np.random.default_rng(3), 24)
    run = _kernel_flight(circuit.vectors(states), states, circuit, current, cal.temp_c)
    below = run.voltage < cutoff_v
    assert below.any(axis=1).all()
    flown = below.argmax(axis=1) + 1.0
    own = m.times(states, current, cutoff_v)
    assert np.median(np.abs(flown / own - 1.0)) < 0.03, np.c_[flown, own]
    assert np.corrcoef(flown, own)[0, 1] > 0.95  # the draws' spread (capacity, curve, resistances) is carried


def _truth_flight(case, k_stop: int, load: FutureLoad) -> tuple[float, bool]:
    """The truth's SoC at the end of ``load`` from its state after sample ``k_stop`` (the estimator's
    motors), and whether it reached its cut-off on the way."""
    inputs = model_inputs(case.description)
    motors = np.asarray(case.estimator.motors.params, dtype=np.float64)
    run = topology.simulate_vehicle_extended(inputs.topology, inputs.pack_matrix[None], case.truth[None, None],
                                             np.ones(1, dtype=bool), motors[None], case.truth_run.states[0, k_stop][None, None],
                                             np.full((1, motors.shape[0]), 25.0), load.dt, load.shaft_power_w,
                                             load.ambient_c, record=True)
    return float(run.pack_soc[0, -1, 0]), bool(run.pack_end_step[0, 0] >= 0)


def test_the_route_risk_lands_a_calibrated_pack_on_its_learned_model(half_way):
    from gcs_pdm.service.adapters import route_risk

    case, k_stop, _ = half_way
    est = case.estimator
    kernel_only = copy.deepcopy(est)
    kernel_only.calib = [None]
    # a route the truth flies with margin: its landing SoC
    load = FutureLoad.constant(80.0, 300.0, 5.0, 25.0)
    truth, cut_off = _truth_flight(case, k_stop, load)
    assert not cut_off
    got, before = route_risk(est, load, []), route_risk(kernel_only, load, [])
    assert got["landing_samples"] == got["n_samples"]
    p05, p50, p95 = (got["landing_soc"][q] for q in ("p05", "p50", "p95"))
    assert abs(p50 - truth) < 0.03, (got["landing_soc"], truth)
    assert p05 <= truth <= p95
    # the kernel pack (the label's capacity, LLF20's resistance) lands it higher than it will be
    assert before["landing_soc"]["p50"] - truth > 2 * abs(p50 - truth), (before["landing_soc"], truth)
    # a harder route, on which the truth reaches its cut-off: the learned resistance and curve say so
    load = FutureLoad.constant(120.0, 300.0, 5.0, 25.0)
    assert _truth_flight(case, k_stop, load)[1]
    got, before = route_risk(est, load, []), route_risk(kernel_only, load, [])
    assert got["failure_probability"] > 0.9, got
    assert before["failure_probability"] < 0.1, before


def test_packs_that_do_not_self_calibrate_are_left_to_the_kernel():
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.vehicle.presets import PRESETS

    assert CalibratedPacks.of(StateEstimator(vehicle=PRESETS["edge540"])) is None  # a fitted set's filter
    assert CalibratedPacks.of(StateEstimator(vehicle=PRESETS["quad-4s"])) is None  # no voltage seen yet
