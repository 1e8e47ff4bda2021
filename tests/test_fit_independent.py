"""Acceptance on cells no one here wrote: PyBaMM SPMe flights (fixtures/pybamm, scripts/generate_pybamm_flights.py).

Per parameter set (Chen2020, Marquis2019): fit the default (extended) variant on its 8 training
flights, choose on its 2 validation flights, and predict its 2 test flights; fit the one-RC
polynomial-OCV baseline (tests/baseline_one_rc.py) by least squares on the same cleaned training
flights. The bounds of issue 15 are asserted per test flight. The paper variant's figures are in
docs/fitting.md (benchmarks/bench_fit.py --independent produces the whole table).
"""
import json
from pathlib import Path

import numpy as np
import pytest

from baseline_one_rc import fit_baseline
from gcs_pdm.fitting.cleaning import clean_flights
from gcs_pdm.fitting.logs import read_table
from gcs_pdm.fitting.procedure import FitSettings, fit_battery

ROOT = Path(__file__).resolve().parents[1] / "fixtures" / "pybamm"
SETS = ("Chen2020", "Marquis2019")
SETTINGS = FitSettings()  # the defaults of `gcs-pdm fit battery`: the extended variant


def load(set_name):
    manifest = json.loads((ROOT / "manifest.json").read_text())
    return {split: [read_table(ROOT / f["file"], "battery", f["flight"]) for f in manifest["flights"]
                    if f["set"] == set_name and f["split"] == split]
            for split in ("train", "validation", "test")}


def rmse(pred, meas):
    ok = np.isfinite(meas)
    return float(np.sqrt(np.mean((pred[ok] - meas[ok]) ** 2)))


@pytest.fixture(scope="module", params=SETS)
def fitted(request):
    splits = load(request.param)
    result = fit_battery(splits["train"], splits["validation"], splits["test"], SETTINGS)
    train, _, _ = clean_flights(splits["train"])
    test, _, _ = clean_flights(splits["test"])
    return request.param, result, fit_baseline(train), test


def test_fixture_is_what_the_manifest_says():
    manifest = json.loads((ROOT / "manifest.json").read_text())
    assert {f["set"] for f in manifest["flights"]} == set(SETS)
    for s in SETS:
        fl = [f for f in manifest["flights"] if f["set"] == s]
        assert [f["split"] for f in fl].count("test") == 2 and [f["split"] for f in fl].count("train") == 8
        assert any(f["reached_cutoff"] for f in fl)
    ambients = [f["ambient_c"] for f in manifest["flights"]]
    assert min(ambients) <= 1.0 and max(ambients) >= 34.0
    assert sum(p.stat().st_size for p in ROOT.rglob("*")) < 3e6


def test_extended_variant_beats_the_baseline_on_every_test_flight(fitted):
    set_name, result, baseline, test = fitted
    assert result.model == "extended" and result.thermal["fitted"]
    learned = {e["flight"]: e for e in result.errors["learned"]["test"]["flights"]}
    assert set(learned) == {f.name for f in test}
    for f in test:
        v_ext = learned[f.name]["voltage"]["rmse"]
        t_ext = learned[f.name]["temperature"]["rmse"]
        v_base = rmse(baseline.voltage(f), f.voltage_v)
        assert v_ext <= 0.050, f"{set_name} {f.name}: voltage RMSE {v_ext * 1000:.1f} mV > 50 mV"
        assert v_ext <= 0.5 * v_base, (f"{set_name} {f.name}: voltage RMSE {v_ext * 1000:.1f} mV not half the "
                                       f"baseline's {v_base * 1000:.1f} mV")
        assert t_ext <= 0.8, f"{set_name} {f.name}: temperature RMSE {t_ext:.2f} K > 0.8 K"
