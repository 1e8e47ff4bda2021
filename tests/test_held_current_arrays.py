"""The held-current flight without the compiler (``estimation.held_current_arrays``, a first
replay's) gives the compiled flight's numbers bit for bit: the first replay on a cold cache and
every later one print the same trace."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.estimation import held_current_arrays, prediction
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.models import kernel
from gcs_pdm.models.params import builtin


@pytest.fixture(scope="module")
def drawn():
    """A held-current Monte Carlo's rows as a replay's trace draws them (64 samples x 4 packs),
    some packs near empty, some cool, one row's state NaN."""
    est = StateEstimator(builtin("paper_si"))
    p = est.packs.params
    est.packs.mean[:, kernel.S_QB] = p[:, kernel.I_QMAX] - (1.0 - np.array([0.9, 0.5, 0.25, 0.1])) * p[:, kernel.I_CMAX]
    est.packs.mean[:, kernel.S_T] = 20.0
    inputs = prediction.held_current_inputs(est, np.full(4, 17.5), current_a=np.array([10.0, 25.0, 60.0, 0.5]))
    samples = prediction.draw_held_current(inputs, rng=np.random.default_rng(3), n_samples=64)
    (variant, sel, params, states), = samples.rows
    assert variant == "paper"
    states = states.copy()
    states[5] = np.nan
    return params, states, samples.dt, np.tile(inputs.current_a, 64)[sel], np.tile(inputs.cutoff_v, 64)[sel], inputs.ambient_c


def test_arrays_fly_as_the_compiled_kernel(drawn):
    params, states, dt, current, cutoff, ambient = drawn
    assert held_current_arrays.applies(dt, kernel.DEFAULT_MAX_DT)
    compiled_end, compiled_peak = prediction._held_current_to_cutoff(params, states, dt, current, cutoff, ambient, "paper")
    end, peak = held_current_arrays.fly(params, states, dt, current, cutoff, ambient)
    # the rows cover the cases: cut off early, late, never within the horizon, and NaN
    assert (compiled_end >= 0).sum() > 10 and (compiled_end == -1).sum() > 10
    assert np.isnan(compiled_peak).sum() == 1
    np.testing.assert_array_equal(end, compiled_end)
    assert np.array_equal(peak, compiled_peak, equal_nan=True)
    assert peak.tobytes() == compiled_peak.tobytes()  # bit for bit, NaN included


def test_only_one_unsplit_interval_length_applies():
    assert not held_current_arrays.applies(np.array([5.0, 5.0, 4.0]), 10.0)   # uneven
    assert not held_current_arrays.applies(np.array([20.0, 20.0]), 10.0)      # cut into sub-steps
    assert not held_current_arrays.applies(np.array([0.0, 0.0]), 10.0)        # no time passes
    assert held_current_arrays.applies(np.full(720, 5.0), 10.0)
