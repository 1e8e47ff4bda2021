"""Issue 29: the pack's own history as its next flight's prior. A flight's record is fitted after it
lands (``packs.flight_curve``: the curve's shape, offset and scale, the capacity); the next flight's
filter starts from that (``packs.priors.prior_with_history``), where the chemistry's published
curves could not tell the cell's SoC on the flat part of its curve."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gcs_pdm.estimation.calibration import PackPrior
from gcs_pdm.estimation.curve_bank import pack_calibrator
from gcs_pdm.models.chemistry import SOC_GRID
from gcs_pdm.models.curve_hypotheses import CURVE_HYPOTHESES
from gcs_pdm.packs.flight_curve import fit_flight_curve
from gcs_pdm.packs.priors import prior_with_history
from gcs_pdm.packs.trend import estimator_priors
from gcs_pdm.packs.health import HealthPoint

LCO = CURVE_HYPOTHESES["lipo"][1].curve
CELLS, Q_AH = 4, 5.0
#: a cell charged to 4.10 V whose middle rests up to 45 mV below the published LCO pouch's (a shape
#: no offset-and-scale within the prior makes: Marquis2019 differs from it so)
OWN = tuple(float(v - 0.045 * math.sin(math.pi * s) ** 2) for s, v in zip(SOC_GRID, LCO.ocv_cell_v))
DECLARED = PackPrior("lipo", CELLS, Q_AH * 3600.0, full_cell_v=4.10)


def _fly(start_soc: float, until_soc: float, seed: int, capacity_ah: float = 1.1 * Q_AH):
    """A pack on ``OWN`` (the filter's own circuit, 10 mV noise): 60 s at rest, 0.8-2 C legs down to
    ``until_soc``, 120 s at rest. (time, current, voltage, temperature, true SoC)."""
    rng = np.random.default_rng(seed)
    amps = [0.0] * 60
    soc = start_soc
    while soc > until_soc:
        leg = [rng.uniform(0.8, 2.0) * Q_AH] * int(rng.uniform(30, 120))
        amps += leg
        soc -= sum(leg) / (capacity_ah * 3600.0)
    amps += [0.0] * 120
    r0 = CELLS * LCO.r0_cell_ah / Q_AH
    a = math.exp(-1.0 / LCO.tau1_s)
    soc, v1, rows = start_soc, 0.0, []
    grid = np.asarray(SOC_GRID)
    for k, i in enumerate(amps):
        soc -= i / (capacity_ah * 3600.0)
        v1 = a * v1 + (1.0 - a) * LCO.r1_ratio * r0 * i
        v = CELLS * float(np.interp(soc, grid, OWN)) - r0 * i - v1 + rng.normal(0.0, 0.010)
        rows.append((float(k), i, v, 25.0, soc))
    return tuple(np.array(c) for c in zip(*rows))


def _largest_error_after_5_min(prior, flight) -> float:
    t, i, v, temp, truth = flight
    cal = pack_calibrator(prior)
    errors = []
    for k in range(t.size):
        if not cal.initialised:
            cal.initialise(t[k], v[k], i[k], temp[k])
        else:
            cal.step(t[k], 1.0, i[k], v[k], temp[k])
        if t[k] >= 300.0:
            errors.append(abs(cal.soc - truth[k]))
    return max(errors)


@pytest.fixture(scope="module")
def first_flight_fit():
    t, i, v, temp, _ = _fly(1.0, 0.15, seed=3)
    return fit_flight_curve(t, i, v, temp, DECLARED)


def test_a_flight_from_full_tells_the_cells_curve_and_capacity(first_flight_fit):
    fit = first_flight_fit
    assert fit["curve"] == "lco_4v10" and fit["started_full"]
    # a free shape and the capacity trade (a curve stretched along its SoC explains the same flight
    # at another capacity): only the published shape's prior holds them, so the capacity is loose...
    assert fit["capacity_ah"] == pytest.approx(1.1 * Q_AH, rel=0.10)
    learned = np.asarray(fit["ocv_cell_v"])
    assert np.all(np.diff(learned) > 0)
    # ...and so does the start (0.98 here: the top's shape against its SoC). What the flight measured,
    # the rested voltage against the charge drawn from the start, is learned where it was flown to
    # the noise's size, where the published curve misses it by up to 45 mV
    drawn_ah = np.linspace(0.05, 0.8, 16) * 1.1 * Q_AH
    grid = np.asarray(SOC_GRID)
    truth = np.interp(1.0 - drawn_ah / (1.1 * Q_AH), grid, OWN)
    miss = np.abs(np.interp(fit["start_soc"] - drawn_ah / fit["capacity_ah"], grid, learned) - truth)
    published = np.abs(np.interp(1.0 - drawn_ah / (1.1 * Q_AH), grid, LCO.ocv_cell_v) - truth)
    assert miss.max() < 0.008 and published.max() > 0.04


def test_the_next_flight_starts_from_the_learned_curve(first_flight_fit):
    # plugged in at 55 %, on the flat middle where the published curve reads it ~0.15 off
    second = _fly(0.55, 0.25, seed=4)
    told = prior_with_history(DECLARED, {"curve": first_flight_fit}, "SN-1")
    assert told.curve is not None and "learned" in told.curve.name
    assert told.capacity_source.startswith("pack history (SN-1)")
    without = _largest_error_after_5_min(DECLARED, second)
    with_history = _largest_error_after_5_min(told, second)
    assert without > 0.08
    assert with_history < 0.05


def test_what_a_fit_cannot_tell_is_not_carried(first_flight_fit):
    assert prior_with_history(DECLARED, {"curve": {"why": "too short"}}) is DECLARED
    unsure = {**first_flight_fit, "weight": 0.7}
    assert prior_with_history(DECLARED, {"curve": unsure}) is DECLARED
    described = replace(DECLARED, curve=LCO)  # a written description's own curve is never replaced
    assert prior_with_history(described, {"curve": first_flight_fit}) is described
    # too little drawn: the shape and the capacity stay open, and the fit says why
    t, i, v, temp, _ = _fly(0.9, 0.8, seed=5)
    assert "drawn" in fit_flight_curve(t, i, v, temp, DECLARED)["why"]


def test_the_latest_fitted_flight_is_the_estimators_curve_prior(first_flight_fit):
    def point(curve):
        return HealthPoint(pack_id="SN-1", start_s=0.0, end_s=900.0, capacity_ah=None, capacity_sd_ah=None,
                           resistance_25c_ohm=None, resistance_sd_ohm=None, charge_ah=3.0, energy_wh=40.0,
                           equivalent_cycles=0.6, depth_of_discharge=None, peak_temperature_c=None,
                           nominal_capacity_ah=Q_AH, cells_series=CELLS, curve=curve)

    priors = estimator_priors([point(first_flight_fit), point({"why": "too little drawn"})])
    assert priors["curve"] is not None and priors["curve"]["capacity_ah"] == first_flight_fit["capacity_ah"]
    assert HealthPoint.from_dict(point(first_flight_fit).to_dict()).curve == first_flight_fit
