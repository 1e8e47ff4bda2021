"""The extended variant on the one kernel: OCV curve, exact steps, batching, parameter sets."""
import dataclasses

import numpy as np
import pytest

from gcs_pdm.models import kernel
from gcs_pdm.models.params import (CHEMISTRIES, OCV_PER_CELL, ParameterError, ParameterSet, default_set,
                                   extended_default)


def _vec(chemistry="lipo", **changes):
    d = extended_default(chemistry)
    d.update(changes)
    return np.array([d[k] for k in kernel.EXT_PACK_PARAMS])


@pytest.mark.parametrize("chemistry", CHEMISTRIES)
def test_ocv_passes_through_its_knots_and_is_monotone(chemistry):
    p = _vec(chemistry)
    knots = kernel.open_circuit_voltage(p, kernel.EXT_OCV_SOC)
    np.testing.assert_allclose(knots, 5 * np.asarray(OCV_PER_CELL[chemistry]), atol=1e-12)
    soc = np.linspace(-0.1, 1.1, 2001)
    v = kernel.open_circuit_voltage(p, soc)
    assert np.all(np.diff(v) > 0)


def test_ocv_stays_monotone_for_any_positive_increments():
    rng = np.random.default_rng(3)
    soc = np.linspace(0, 1, 1001)
    for _ in range(50):
        p = _vec(**{f"docv_{k}": float(rng.lognormal(-2, 2)) for k in range(1, kernel.N_OCV_KNOTS)})
        assert np.all(np.diff(kernel.open_circuit_voltage(p, soc)) > 0)


def test_rest_voltage_gives_back_the_soc():
    p = _vec()
    for soc in (0.1, 0.5, 0.93):
        v = kernel.open_circuit_voltage(p, soc)[0]
        assert kernel.extended_rest_soc(p, v, 0.0, 25.0)[0] == pytest.approx(soc, abs=1e-9)


def test_constant_current_step_is_exact_for_the_rc_pairs():
    # with f frozen (no Arrhenius, no low-SoC rise, no kinetics) and a flat OCV the RC voltages have
    # a closed form; one 10 s step must equal ten 1 s steps and the analytic value
    p = _vec(E_r=0.0, k_soc=0.0, b_ct=1e-12, **{f"docv_{k}": 1e-9 for k in range(1, kernel.N_OCV_KNOTS)})
    x0 = kernel.initial_extended_state(p, 0.8, 25.0)
    i = 20.0
    one = kernel.simulate_packs(p, x0, np.array([0.0, 10.0]), np.array([0.0, i]), 25.0, variant="extended")
    ten = kernel.simulate_packs(p, x0, np.r_[0.0, np.ones(10)], np.r_[0.0, np.full(10, i)], 25.0,
                                variant="extended")
    ocv = kernel.open_circuit_voltage(p, 0.8)[0]
    exact = ocv - i * p[kernel.E_R0] - sum(i * p[r] * (1 - np.exp(-10.0 / p[t]))
                                          for r, t in ((kernel.E_R1, kernel.E_TAU1), (kernel.E_R2, kernel.E_TAU2)))
    assert one.voltage[0, -1] == pytest.approx(exact, abs=1e-6)
    assert ten.voltage[0, -1] == pytest.approx(exact, abs=1e-6)


def test_cold_pack_sags_more_and_heats_up():
    p = _vec()
    n = 600
    runs = {}
    for t_amb in (0.0, 30.0):
        x0 = kernel.initial_extended_state(p, 0.9, t_amb)
        runs[t_amb] = kernel.simulate_packs(p, x0, np.ones(n), np.full(n, 25.0), t_amb, variant="extended")
    assert runs[0.0].voltage[0, -1] < runs[30.0].voltage[0, -1] - 0.05
    assert runs[0.0].temperature[0, -1] > 0.5


def test_measured_temperature_drives_the_resistances():
    p = _vec()
    x0 = kernel.initial_extended_state(p, 0.9, 25.0)
    n = 100
    warm = kernel.simulate_packs(p, x0, np.ones(n), np.full(n, 25.0), 25.0, variant="extended",
                                 measured_temperature=np.full(n, 40.0))
    cold = kernel.simulate_packs(p, x0, np.ones(n), np.full(n, 25.0), 25.0, variant="extended",
                                 measured_temperature=np.full(n, 0.0))
    assert cold.voltage[0, -1] < warm.voltage[0, -1]


def test_batched_serial_and_parallel_equal_one_at_a_time():
    rng = np.random.default_rng(1)
    P = np.array([_vec(R_0=float(r)) for r in rng.uniform(0.01, 0.05, 7)])
    X = kernel.initial_extended_state(P, rng.uniform(0.5, 1.0, 7), 20.0)
    n = 300
    cur = rng.uniform(0, 40, n)
    batch = kernel.simulate_packs(P, X, np.ones(n), cur, 20.0, variant="extended")
    par = kernel.simulate_packs(P, X, np.ones(n), cur, 20.0, variant="extended", parallel=True)
    for j in range(7):
        one = kernel.simulate_packs(P[j], X[j], np.ones(n), cur, 20.0, variant="extended")
        np.testing.assert_array_equal(one.voltage[0], batch.voltage[j])
    np.testing.assert_array_equal(par.voltage, batch.voltage)
    np.testing.assert_array_equal(par.temperature, batch.temperature)


def test_paper_variant_parallel_equals_serial():
    P = default_set().pack_matrix()
    X = kernel.initial_pack_state(P, 0.9, 20.0)
    cur = np.linspace(0, 30, 200)
    a = kernel.simulate_packs(P, X, np.ones(200), cur, 20.0)
    b = kernel.simulate_packs(P, X, np.ones(200), cur, 20.0, parallel=True)
    np.testing.assert_array_equal(a.voltage, b.voltage)


def test_unknown_variant_is_refused():
    with pytest.raises(ValueError, match="variant"):
        kernel.simulate_packs(default_set().pack_matrix(), np.zeros((4, 4)), np.ones(3), np.ones(3), 20.0,
                              variant="magic")


def test_parameter_set_round_trips_the_variant():
    ps = default_set()
    pack = dataclasses.replace(ps.packs["LLF20"], model="extended", extended=extended_default("li-ion"))
    q = ps.with_pack("LLF20", pack)
    r = ParameterSet.from_json(q.to_json())
    assert r == q
    assert r.packs["LLF20"].model == "extended" and r.packs["ULA20"].model == "paper"
    np.testing.assert_array_equal(r.packs["LLF20"].extended_vector(), _vec("li-ion"))
    assert ParameterSet.from_json(ps.to_json()) == ps


def test_parameter_set_refuses_a_non_monotone_ocv_and_unknown_variant():
    ps = default_set()
    bad = dict(extended_default(), docv_3=-0.1)
    with pytest.raises(ParameterError, match="docv_3"):
        ps.with_pack("LLF20", dataclasses.replace(ps.packs["LLF20"], model="extended", extended=bad)).replace()
    with pytest.raises(ParameterError, match="model"):
        ParameterSet(name="x", packs={**ps.packs, "LLF20": dataclasses.replace(ps.packs["LLF20"], model="magic")},
                     motor=ps.motor)
    with pytest.raises(ParameterError, match="extended"):
        ParameterSet(name="x", packs={**ps.packs, "LLF20": dataclasses.replace(ps.packs["LLF20"], model="extended")},
                     motor=ps.motor)
