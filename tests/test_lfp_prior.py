"""A LiFePO4 pack read through its chemistry (issue 29): its plateau says little about the SoC, and the σ
must say so (docs/notes/2026-11-28-lfp-curve.md)."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.estimation.calibration import PackCalibrator, PackPrior, prior_of_spec
from gcs_pdm.models.chemistry import chemistry
from gcs_pdm.models.curve_hypotheses import CURVE_FAMILY_SPREAD
from gcs_pdm.replay.calibration_eval import pybamm_cell_curve, pybamm_flight_soc
from gcs_pdm.vehicle.description import PackSpec

ROOT = Path(__file__).resolve().parents[1]
LFP_FLIGHTS = ROOT / "fixtures" / "pybamm_lfp"
CELLS = 4
CAPACITY_C = 10.0 * 3600.0


#: the published cell's rested curve as PyBaMM gives it (``curves.json``), not the module's copy
PUBLISHED = pybamm_cell_curve(LFP_FLIGHTS, "Prada2013", "lifepo4")


def _rested(cell_v: float, prior: PackPrior | None = None) -> PackCalibrator:
    cal = PackCalibrator(prior if prior is not None else PackPrior("lifepo4", CELLS, CAPACITY_C))
    cal.initialise(0.0, CELLS * cell_v, 0.0, 25.0)
    for k in range(1, 31):
        cal.step(float(k), 1.0, 0.0, CELLS * cell_v, 25.0)
    return cal


@pytest.mark.parametrize("soc", [0.3, 0.5, 0.8])
def test_a_pack_resting_on_the_published_cells_plateau_is_inside_its_2sigma(soc):
    # the published A123 cell (Prada2013) rests 20-80 mV below the table on the plateau: read through
    # the table alone that was 0.2-0.4 of SoC off with a σ of about 0.05
    cal = _rested(PUBLISHED.ocv(soc))
    assert abs(cal.soc - soc) <= 2.0 * cal.soc_sd, (cal.soc, cal.soc_sd)
    assert abs(cal.soc - soc) > 0.05  # the table's reading is off: it is the σ that holds the truth


def test_the_family_carries_the_published_cells_curve():
    family = CURVE_FAMILY_SPREAD["lifepo4"]
    assert family.count_in_flight
    assert any(np.allclose(c.ocv_cell_v, PUBLISHED.ocv_cell_v, atol=1e-3) for c in family.curves)
    assert any(c == chemistry("lifepo4") for c in family.curves)


@pytest.mark.parametrize("full_cell_voltage", [None, 3.45, 3.6])
def test_a_described_lfp_pack_without_its_own_model_keeps_both_curves(full_cell_voltage):
    # a provisional (derived) description, or one without a parameter set, reads the chemistry's
    # table with its declared (or default 3.45 V) full cell: the declaration must not drop the
    # published cell (``CurveFamilySpread.given_full``), nor a 3.6 V charge voltage pick one
    spec = PackSpec(name="lfp", mavlink_battery_id=0, cells_series=CELLS, capacity_mah=10000.0, chemistry="lifepo4",
                    full_cell_voltage=full_cell_voltage)
    prior = prior_of_spec(spec)
    assert len(prior.curve_family_spread.curves) == 2
    cal = _rested(PUBLISHED.ocv(0.5), prior)
    assert abs(cal.soc - 0.5) <= 2.0 * cal.soc_sd, (cal.soc, cal.soc_sd)


def test_a_pack_resting_on_the_tables_own_curve_reads_it():
    cal = _rested(chemistry("lifepo4").ocv(0.6))
    assert abs(cal.soc - 0.6) <= 0.02
    assert cal.soc_sd >= CURVE_FAMILY_SPREAD["lifepo4"].rest_soc_sd  # the other curve may still be the pack's


def test_in_flight_the_plateau_teaches_the_circuit_and_the_count_carries_the_soc():
    cal = _rested(chemistry("lifepo4").ocv(0.8))
    start = cal.soc
    v = CELLS * chemistry("lifepo4").ocv(0.8)
    amps = 20.0
    for k in range(31, 331):  # 5 min at 2C, the voltage kept on the plateau (sagging a little)
        cal.step(float(k), 1.0, amps, v - 0.15, 25.0)
    drawn = 300.0 * amps / CAPACITY_C
    assert cal.soc == pytest.approx(start - drawn, abs=0.01)


@pytest.mark.parametrize("flight", json.loads((LFP_FLIGHTS / "manifest.json").read_text())["flights"],
                         ids=lambda f: f["flight"])
def test_pybamm_lfp_flights_from_the_chemistry_prior_hold_the_truth_in_2sigma(flight):
    logging.disable(logging.WARNING)
    try:
        sets = json.loads((LFP_FLIGHTS / "manifest.json").read_text())["sets"]
        track, _ = pybamm_flight_soc(LFP_FLIGHTS, flight, sets)
    finally:
        logging.disable(logging.NOTSET)
    s = track.summary(300.0)
    assert s["within_2sd"] >= 0.9, s
    assert np.isfinite(track.soc).all()
