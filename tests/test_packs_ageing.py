"""The packs' health points and forecast on PyBaMM's ageing cells (fixtures/pybamm_ageing, made by
scripts/generate_pybamm_flights.py --ageing): O'Kane 2022 (SEI growth and lithium plating) and Chen
2020 (SEI growth, its film's resistance), flown from their first flight past 80 % capacity, with the
true C/20 capacity and 1-s pulse resistance at each flight. The evaluation is
scripts/evaluate_pack_ageing.py's (its figures are in docs/packs.md)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures" / "pybamm_ageing"
sys.path.insert(0, str(ROOT / "scripts"))  # the evaluation; tests/ is not a package

pytestmark = pytest.mark.skipif(not (FIXTURES / "manifest.json").exists(), reason="no ageing fixtures")


@pytest.fixture(scope="module")
def results():
    from evaluate_pack_ageing import evaluate

    return evaluate(FIXTURES)


def test_the_fixtures_are_two_degradation_models_past_80_percent():
    man = json.loads((FIXTURES / "manifest.json").read_text())
    assert set(man["sets"]) == {"OKane2022", "Chen2020"}
    assert "irreversible" in man["sets"]["OKane2022"]["options"]["lithium plating"]  # (negative, positive)
    for name, entry in man["sets"].items():
        caps = [f["true_capacity_ah"] for f in man["flights"] if f["set"] == name]
        assert caps[-1] < 0.8 * caps[0], name
        assert "solvent-diffusion limited" in entry["options"]["SEI"]


def test_the_truth_is_measured_at_the_cells_own_wear_rate():
    """Chen2020 ages with its SEI growth compressed x8000: a 20-h C/20 discharge at that rate loses
    lithium to the SEI during the measurement (6 % of the fresh cell), so its truth is measured with
    the rate undone; O'Kane2022's factor slows plating and its truth is at the flights' rates."""
    man = json.loads((FIXTURES / "manifest.json").read_text())
    assert man["sets"]["Chen2020"]["truth_at_native_rates"] == ["SEI solvent diffusivity [m2.s-1]"]
    assert man["sets"]["OKane2022"]["truth_at_native_rates"] == []
    for f in man["flights"]:
        compressed = f["c20_capacity_at_compressed_rates_ah"]
        if f["set"] == "Chen2020":
            assert f["true_capacity_ah"] > compressed * 1.005, f["flight"]
        else:
            assert f["true_capacity_ah"] == compressed, f["flight"]


def test_each_flights_capacity_is_near_the_truth(results):
    for name, r in results.items():
        errors = r["capacity_errors"]
        assert all(e == e for e in errors), f"{name}: a flight's capacity unknown"
        # measured (docs/notes/2026-11-27-pack-capacity.md), on the liion chemistry's electrodes
        # (what the live service and packs ingest read on): O'Kane 44/44 within 3 %, worst 2.9 %,
        # mean |error| 1.2 %; Chen 63/64, worst 3.5 % (its first flight: 1 % of its lithium lost to
        # the compressed SEI between the rests), mean 0.9 %. Before the truth was measured at the
        # cell's own SEI rate, Chen's leaned +1.7 % (60/64)
        assert r["capacity_within_3pct"] >= r["flights"] - 1, (name, errors)
        assert r["capacity_abs_error_max"] < 0.036, (name, errors)
        assert r["capacity_abs_error_mean"] < 0.013, (name, errors)
        assert abs(sum(errors) / len(errors)) < 0.01, (name, errors)  # no lean: measured -0.3 % / +0.9 %
        # the σ is a claim: 2σ covers the truth (measured 44/44 and 64/64)
        assert r["capacity_truth_within_2sd"] >= 0.97 * r["flights"], name
    assert results["OKane2022"]["capacity_abs_error_max"] <= 0.03


def test_the_resistance_trend_follows_the_truth(results):
    chen = results["Chen2020"]  # the SEI film's resistance grows: the truth rises by half
    assert chen["resistance_growth_true"] > 1.3
    assert chen["resistance_rank_correlation"] > 0.9
    assert chen["resistance_growth_estimated"] > 1.3


def test_the_retirement_forecast_from_the_first_half_of_life_is_within_20_percent(results):
    for name, r in results.items():
        f = r["forecast_from_first_half"]
        assert f is not None and f["forecast_cycles"] is not None, name
        assert abs(f["error"]) < 0.2, (name, f)
