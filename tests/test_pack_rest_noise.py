"""A rest is a rest through the current sensor's noise (gcs_pdm/packs/health.py).

The rest threshold is 0.02C: 0.156 A on a 7.8 Ah pack, about 3σ of a current sensor with 0.05 A of
noise (the PyBaMM flights'). Read sample by sample, one noisy sample in a 15-min rest after landing
ended the rest there and the capacity was "unknown: no rest after landing" on 9 of 13 such flights
(docs/notes/2026-11-28-history-prior.md). The rest's edges are read on the current's running median.
"""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.packs.cell_curves import capacity_reading, pack_health_point, rested_cell_voltage
from gcs_pdm.packs.health import HealthSettings
from gcs_pdm.packs.synthetic import pack_profile

RATED_AH, TRUE_AH, CELLS, R_OHM = 7.8, 7.4, 4, 0.02
CURRENT_NOISE_A = 0.05


def noisy_flight(seed: int, rest_before_s: float = 120.0):
    """A lipo pack's flight with a 2-min (or ``rest_before_s``) rest before and a 15-min rest after,
    sampled at 2 Hz: its rested voltage on the chemistry's curve less the ohmic drop, the current
    read with 0.05 A of noise."""
    t, i, _ = pack_profile(minutes=13.0 + (rest_before_s + 900.0) / 60.0, rest_before_s=rest_before_s,
                           rest_after_s=900.0, seed=seed)
    drawn = np.concatenate([[0.0], np.cumsum(0.5 * (i[1:] + i[:-1]) * np.diff(t))]) / 3600.0
    reading = capacity_reading("lipo", RATED_AH)
    v = CELLS * rested_cell_voltage(reading, TRUE_AH, drawn) - R_OHM * i
    rng = np.random.default_rng(seed)
    return t, i + rng.normal(0.0, CURRENT_NOISE_A, t.size), v + rng.normal(0.0, 0.002, t.size)


@pytest.mark.parametrize("seed", (1, 2, 3))
def test_a_noisy_current_at_rest_does_not_end_the_rest(seed):
    t, i, v = noisy_flight(seed)
    rest_a = HealthSettings().rest_c_rate * RATED_AH
    after = t >= t[-1] - 900.0 + 1.0
    assert np.any(np.abs(i[after]) > rest_a)  # the noise does cross the threshold in the rest
    hp = pack_health_point("SN-1", t, i, v, None, chemistry="lipo", nominal_capacity_ah=RATED_AH, cells_series=CELLS)
    assert hp.capacity_ah is not None, hp.why
    assert hp.capacity_ah == pytest.approx(TRUE_AH, rel=0.03)


@pytest.mark.parametrize("seed", (1, 3, 4))
def test_a_noisy_current_in_a_long_rest_before_keeps_the_take_off_step(seed):
    # the take-off step counts when it is within 120 s of the first load: read sample by sample, a
    # noisy sample minutes earlier in a 15-min rest was the first load (3 of 4 seeds: the resistance
    # became the median over the flight's steps, which mixes every SoC)
    t, i, v = noisy_flight(seed, rest_before_s=900.0)
    rest_a = HealthSettings().rest_c_rate * RATED_AH
    assert np.any(np.abs(i[t < 900.0 - 120.0]) > rest_a)  # the noise does cross the threshold long before
    hp = pack_health_point("SN-1", t, i, v, None, chemistry="lipo", nominal_capacity_ah=RATED_AH, cells_series=CELLS)
    assert hp.method["resistance"].startswith("the take-off step"), hp.method["resistance"]
    assert hp.resistance_25c_ohm == pytest.approx(R_OHM, rel=0.05)
