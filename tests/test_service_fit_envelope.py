"""The vehicle in flight against the conditions its packs' models were fitted on (service.fit_envelope).

A learned set carries each fitted pack's training envelope; the service says in /status, with a
warning banner, when a pack runs hotter, colder or harder than any training flight, and clears it
only back inside the training span (no flicker at the margin)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_pdm.fitting.envelope import CURRENT_MARGIN_REL, TEMPERATURE_MARGIN_K, outside_training
from gcs_pdm.service.fit_envelope import FitEnvelopeWatch, fit_envelope_warnings, training_envelopes

TRAINING = {"pack_temperature_c": [5.0, 40.0], "ambient_c": [0.0, 30.0], "sustained_current_a": 20.0}
PROVENANCE = {"base": "paper", "packs": {"A": {"learned": ["R_0"], "training_envelope": TRAINING},
                                         "B": {"learned": ["R_0"]}}}


def test_the_rule_is_the_fits_margins():
    hot = 40.0 + TEMPERATURE_MARGIN_K
    assert outside_training(TRAINING, (hot - 0.1, hot - 0.1), None, None) == []
    assert outside_training(TRAINING, (hot + 0.1, hot + 0.1), None, None) == [
        "pack temperature reaches 42.1 °C, above the training flights' 40.0 °C"]
    assert outside_training(TRAINING, None, (-2.5, -2.5), None) == [
        "air temperature goes down to -2.5 °C, below the training flights' 0.0 °C"]
    assert outside_training(TRAINING, None, None, 20.0 * (1 + CURRENT_MARGIN_REL) - 0.01) == []
    assert outside_training(TRAINING, None, None, 22.5) == [
        "sustained current reaches 22.5 A, above the training flights' 20.0 A"]
    # margins scaled to zero: anything past the training span itself
    assert outside_training(TRAINING, (40.5, 40.5), None, 20.5, margin_scale=0.0) == [
        "pack temperature reaches 40.5 °C, above the training flights' 40.0 °C",
        "sustained current reaches 20.5 A, above the training flights' 20.0 A"]
    # what a log or a vehicle does not measure is not judged
    assert outside_training({"pack_temperature_c": None, "ambient_c": None, "sustained_current_a": None},
                            (90.0, 90.0), (50.0, 50.0), 500.0) == []


def test_only_fitted_packs_have_an_envelope():
    assert training_envelopes(PROVENANCE) == {"A": TRAINING}
    assert training_envelopes({"source": "paper Tables I and II"}) == {}
    assert training_envelopes(None) == {}
    watch = FitEnvelopeWatch()
    assert watch.update(0.0, {}, ["A", "B"], [20.0, 20.0], 15.0, [0.0, 0.0]) is None


def test_the_sustained_current_is_the_last_minutes_charge():
    watch = FitEnvelopeWatch()
    amps = 12.0
    currents = [watch.sustained_current("A", float(t), amps * t) for t in range(0, 120)]
    assert all(c is None for c in currents[:54])           # under a minute seen: not judged
    assert all(c == pytest.approx(amps) for c in currents[54:])
    # a burst of 3 s at 100 A is not sustained; a minute of it is
    q = amps * 119
    for t in range(120, 123):
        q += 100.0
        burst = watch.sustained_current("A", float(t), q)
    assert burst < 20.0
    for t in range(123, 185):
        q += 100.0
        sustained = watch.sustained_current("A", float(t), q)
    assert sustained == pytest.approx(100.0, rel=0.02)
    # message time going backwards (a replay restarted): the history is dropped, not mixed
    assert watch.sustained_current("A", 10.0, 0.0) is None


def fly(watch, temps, amps, air=15.0, t0=0.0):
    """One status tick a second: pack A at temps[k] °C drawing amps A; the last record."""
    rec = None
    q = 0.0
    for k, temp in enumerate(temps):
        q += amps
        rec = watch.update(t0 + k, {"A": TRAINING}, ["A", "B"], [temp, 25.0], air, [q, 0.0])
    return rec


def test_a_pack_past_its_training_temperatures_is_said_to_extrapolate_and_cleared_inside():
    watch = FitEnvelopeWatch()
    rec = fly(watch, np.linspace(30.0, 45.0, 90), amps=10.0)
    a = rec["packs"]["A"]
    assert a["state"] == "outside" and rec["outside"] == ["A"] and "B" not in rec["packs"]
    assert a["outside"] == ["pack temperature reaches 45.0 °C, above the training flights' 40.0 °C"]
    assert a["now"]["sustained_current_a"] == pytest.approx(10.0) and a["training"] == TRAINING
    assert "pack A: pack temperature reaches 45.0 °C" in rec["reason"] and "refit" in rec["reason"]
    (banner,) = fit_envelope_warnings(rec)
    assert banner["kind"] == "outside_fit_envelope" and banner["level"] == "warning" and "A" in banner["title"]
    # cooling back to 41 °C: inside the margin but not the span: still outside (no flicker)
    rec = watch.update(100.0, {"A": TRAINING}, ["A"], [41.0], 15.0, [1000.0])
    assert rec["packs"]["A"]["state"] == "outside"
    rec = watch.update(101.0, {"A": TRAINING}, ["A"], [39.5], 15.0, [1010.0])
    assert rec["packs"]["A"]["state"] == "inside" and rec["outside"] == [] and rec["reason"] is None
    assert fit_envelope_warnings(rec) == []
    # and going up again, it takes the full margin to warn again
    rec = watch.update(102.0, {"A": TRAINING}, ["A"], [41.5], 15.0, [1020.0])
    assert rec["packs"]["A"]["state"] == "inside"


def test_a_pack_drawing_more_than_any_training_flight_for_a_minute_is_outside():
    rec = fly(FitEnvelopeWatch(), [25.0] * 90, amps=30.0)
    assert rec["packs"]["A"]["outside"] == ["sustained current reaches 30.0 A, above the training flights' 20.0 A"]


def test_unknown_when_nothing_can_be_judged():
    watch = FitEnvelopeWatch()
    rec = watch.update(0.0, {"A": TRAINING}, ["A"], [math.nan], math.nan, [0.0])
    a = rec["packs"]["A"]
    assert a["state"] == "unknown" and a["outside"] == [] and rec["outside"] == []
    assert a["not_judged"] == ["pack temperature", "air temperature", "60-s current"]
    assert a["now"] == {"pack_temperature_c": None, "ambient_c": None, "sustained_current_a": None}
    rec = watch.update(1.0, {"A": TRAINING}, ["A"], [20.0], math.nan, [10.0])
    assert rec["packs"]["A"]["state"] == "inside" and rec["packs"]["A"]["not_judged"] == ["air temperature", "60-s current"]


# ---- end to end: a real fit's set, stored, activated, flown ----------------------------------------

@pytest.fixture(scope="module")
def cold_fit():
    """A small extended fit of one pack on a cold PyBaMM flight (6-8 °C air, 1C): the synthetic vehicle
    flies in 19-20 °C air."""
    from pathlib import Path

    from gcs_pdm.fitting.logs import read_table
    from gcs_pdm.fitting.procedure import FitSettings, fit_battery
    from gcs_pdm.fitting.search import SearchSettings

    root = Path(__file__).resolve().parents[1] / "fixtures" / "pybamm" / "Chen2020"
    train = read_table(root / "chen2020_02.parquet", "battery", "chen2020_02")
    test = read_table(root / "chen2020_11.parquet", "battery", "chen2020_11")
    budget = SearchSettings(starts=2, sa_generations=4, lm_max_nfev=4)
    return fit_battery([train], [train], [test], FitSettings(extended_search=budget, extended_polish_nfev=0,
                                                             extended_ocv_refit_nfev=0, leave_out_misfits=False))


def test_a_learned_set_carries_its_training_envelope_and_warnings(cold_fit):
    from gcs_pdm.fitting.procedure import merge_results
    from gcs_pdm.models.params import ParameterSet, builtin

    merged = merge_results(builtin("previous_si"), {"LLF20": cold_fit})
    prov = ParameterSet.from_json(merged.to_json()).provenance["packs"]["LLF20"]
    assert prov["training_envelope"] == cold_fit.operating_envelope["training"]
    assert prov["training_envelope"]["pack_temperature_c"][1] < 25.0
    assert prov["warnings"] == cold_fit.warnings and any("chen2020_11" in w for w in prov["warnings"])
    assert training_envelopes(merged.provenance) == {"LLF20": prov["training_envelope"]}


def test_status_says_when_the_vehicle_leaves_the_fitted_conditions(tmp_path, cold_fit):
    from fastapi.testclient import TestClient

    from gcs_pdm.estimation.synthetic import fly_synthetic
    from gcs_pdm.fitting.procedure import merge_results
    from gcs_pdm.models.params import builtin
    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.live import LiveLoop
    from gcs_pdm.service.runtime import Service
    from gcs_pdm.sim.truth import true_parameters
    from test_service_live_loop import FakeLink, FakeVehicleMissions, original_mission

    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token="fit-envelope-test-token-01", policy="advise"))
    try:
        loop = LiveLoop(svc, FakeLink(), FakeVehicleMissions(original_mission().items))
        svc.attach_loop(loop)
        client = TestClient(create_app(svc))
        flight = fly_synthetic(true_parameters(), np.random.default_rng(3), duration_s=150.0, initial_soc=0.9)
        frames = sorted(flight.frames, key=lambda fr: fr.time_s)
        half = next(i for i, fr in enumerate(frames) if fr.time_s > 75.0)
        for fr in frames[:half]:
            loop.process(fr)
        # the paper's set: no pack was fitted, nothing to compare with
        status = client.get("/status").json()
        assert status["fit_envelope"] is None and "outside_fit_envelope" not in [
            w["kind"] for w in status.get("warnings", [])]

        svc.store.save_parameter_set(merge_results(builtin("previous_si"), {"LLF20": cold_fit}, name="cold"))
        svc.activate_parameter_set("cold")
        for fr in frames[half:]:
            loop.process(fr)
        status = client.get("/status").json()
        env = status["fit_envelope"]
        assert set(env["packs"]) == {"LLF20"} and env["outside"] == ["LLF20"]
        llf = env["packs"]["LLF20"]
        assert llf["state"] == "outside" and llf["now"]["pack_temperature_c"] == pytest.approx(
            status["packs"]["LLF20"]["temperature_c"], abs=0.01)
        # the synthetic vehicle flies in 19-20 °C air, the fit's only flight in 6-8 °C air
        assert llf["outside"] == [f"air temperature reaches {status['ambient_c']:.1f} °C, above the training "
                                  f"flights' {cold_fit.operating_envelope['training']['ambient_c'][1]:.1f} °C"]
        (banner,) = [w for w in status["warnings"] if w["kind"] == "outside_fit_envelope"]
        assert "LLF20" in banner["title"] and banner["text"] == env["reason"]
    finally:
        svc.close()
