"""The per-frame layouts of issue 18 keep their state where the rest of the code reads it:

- a pack filter bank keeps its arrays in two buffers (``ukf.pack_storage``) that its one-row
  compiled step carves again: the bank's public arrays are those views, and a copy (deepcopy, the
  service's frozen estimator; pickle) steps its own buffers, leaving the original alone;
- the ESC imbalance detector's per-sample path for the pipeline's float readings
  (``update_floats``) and its two-motor shortcut give the general path's numbers.
"""
from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from gcs_pdm.diagnosis.motor_imbalance import EscImbalanceDetector
from gcs_pdm.estimation import ukf
from gcs_pdm.estimation.pack_filter import PackFilterBank
from gcs_pdm.models import kernel
from gcs_pdm.models.params import default_set


def _bank() -> PackFilterBank:
    bank = PackFilterBank(default_set().pack_matrix())
    bank.initialise(np.arange(4), np.array([20.6, 20.5, 20.4, 20.3]), np.full(4, 5.0), np.full(4, 21.0))
    return bank


def _state(bank: PackFilterBank) -> list[np.ndarray]:
    w = bank.consistency
    return [a.copy() for a in (bank.mean, bank.cov, bank.last_innovation, bank.rejected_total,
                               bank.rejected_in_row, bank.relocks, w.buf, w.ints, w.sums)]


def _drive(bank: PackFilterBank, n: int = 300) -> None:
    rng = np.random.default_rng(3)
    for k in range(n):
        v = 20.3 + float(rng.normal(0.0, 0.04)) + (1.5 if 100 <= k < 140 else 0.0)  # spike runs: re-locks
        bank.step_one(k % 4, 0.5, 8.0, 20.0, v, 21.0 + float(rng.normal(0.0, 0.3)))


def test_bank_arrays_are_views_the_compiled_step_updates():
    bank = _bank()
    before = _state(bank)
    _drive(bank)
    after = _state(bank)
    assert all(not np.array_equal(a, b) for a, b in zip(before[:3], after[:3]))
    assert bank.relocks.sum() > 0 and bank.consistency.count.min() > 0
    for view in (bank.params, bank.mean, bank.cov, bank.last_innovation, bank.consistency.buf):
        assert np.shares_memory(view, bank._floats)
    for view in (bank.rejected_total, bank.rejected_in_row, bank.relocks, bank.consistency.ints):
        assert np.shares_memory(view, bank._ints)
    # a change of parameters reaches the compiled step (set_params writes into the buffer)
    row = bank.params[2].copy()
    row[kernel.I_RS] *= 1.5
    bank.set_params(2, row)
    assert ukf.pack_views(bank._floats, bank._ints)[0][2, kernel.I_RS] == row[kernel.I_RS]


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_a_copied_bank_steps_its_own_buffers_bit_for_bit(how):
    bank = _bank()
    _drive(bank, 50)
    twin = copy.deepcopy(bank) if how == "deepcopy" else pickle.loads(pickle.dumps(bank))
    frozen = _state(bank)
    _drive(twin)
    assert all(np.array_equal(a, b) for a, b in zip(frozen, _state(bank))), "the original changed"
    assert np.shares_memory(twin.mean, twin._floats) and not np.shares_memory(twin.mean, bank._floats)
    _drive(bank)
    for a, b in zip(_state(bank), _state(twin)):
        assert np.array_equal(a, b, equal_nan=True)


def test_storage_refuses_arrays_of_the_wrong_shape():
    bank = _bank()
    arrays = ukf.pack_views(bank._floats, bank._ints)
    arrays[1] = np.zeros((4, 5))
    with pytest.raises(ValueError, match="pack_storage"):
        ukf.pack_storage(tuple(arrays), bank.consistency.size)


def _detector(n_motors: int) -> EscImbalanceDetector:
    motor = default_set().motor_vector()
    return EscImbalanceDetector(tuple(f"esc{q}" for q in range(n_motors)), np.tile(motor, (n_motors, 1)))


def test_two_motor_magnitudes_are_the_median_formula():
    det = _detector(2)
    rng = np.random.default_rng(5)
    k = 1.0  # 1 / (M - 1)
    for _ in range(200):
        currents = [float(x) for x in rng.uniform(0.5, 30.0, 2)]
        bus = [float(x) for x in rng.uniform(10.0, 25.0, 2)]
        got = det.magnitudes(currents, bus)
        power = det._powers(currents, bus)
        for q in range(2):
            p_o = float(np.median([power[1 - q]]))
            c = det._i0[q] * bus[q]
            a_q = power[q] + c
            a2, a1, a0 = c * k, (a_q - c) * k + c + p_o, a_q - c - p_o
            disc = a1 * a1 - 4.0 * a2 * a0
            want = (-a1 + math.sqrt(disc)) / (2.0 * a2) if p_o > 0.0 and disc >= 0.0 else math.nan
            assert got[q] == want or (math.isnan(got[q]) and math.isnan(want))


def test_float_path_is_the_general_update():
    """Readings as numpy values and as Python floats give the same samples, faults and events."""
    general, floats = _detector(4), _detector(4)
    rng = np.random.default_rng(9)
    events_g, events_f = [], []
    for k in range(400):
        currents = rng.uniform(8.0, 12.0, 4)
        if k >= 100:
            currents[2] *= 1.5   # motor 2 draws more for the same share: the others look faulted
        bus = rng.uniform(20.0, 21.0, 4)
        events_g += general.update(0.5 * k, currents, bus)
        events_f += floats.update_floats(0.5 * k, currents.tolist(), bus.tolist())
    assert events_g and [(e, f.component, f.magnitude) for e, f in events_g] == \
        [(e, f.component, f.magnitude) for e, f in events_f]
    assert general.samples == floats.samples and general.low_power_skipped == floats.low_power_skipped
    assert {n: f.to_dict() for n, f in general.faults.items()} == {n: f.to_dict() for n, f in floats.faults.items()}
    assert np.array_equal(general.fault_vector(), floats.fault_vector())
