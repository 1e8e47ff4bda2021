"""The vehicle in flight against the conditions its packs' models were fitted on (service.fit_envelope).

A learned set carries each fitted pack's training envelope; the service says in /status, with a
warning banner, when a pack the estimator flies on fitted values runs hotter, colder or harder than
any training flight, and clears it only back inside the training span (no flicker at the margin)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_pdm.models.training_envelope import CURRENT_MARGIN_REL, TEMPERATURE_MARGIN_K, outside_training, training_envelopes
from gcs_pdm.service.fit_envelope import FitEnvelopeWatch, fit_envelope_warnings

TRAINING = {"pack_temperature_c": [5.0, 40.0], "ambient_c": [0.0, 30.0], "sustained_current_a": 20.0}
PROVENANCE = {"base": "paper", "packs": {"A": {"learned": ["R_0"], "training_envelope": TRAINING},
                                         "B": {"learned": ["R_0"]}}}


def reasons(*args, **kw):
    return list(outside_training(TRAINING, *args, **kw).values())


def test_the_rule_is_the_fits_margins():
    hot = 40.0 + TEMPERATURE_MARGIN_K
    assert reasons((hot - 0.1, hot - 0.1), None, None) == []
    assert reasons((hot + 0.1, hot + 0.1), None, None) == [
        "pack temperature reaches 42.1 °C, above the training flights' 40.0 °C"]
    assert reasons(None, (-2.5, -2.5), None) == [
        "air temperature goes down to -2.5 °C, below the training flights' 0.0 °C"]
    assert reasons(None, None, 20.0 * (1 + CURRENT_MARGIN_REL) - 0.01) == []
    assert outside_training(TRAINING, None, None, 22.5) == {
        "current": "sustained current reaches 22.5 A, above the training flights' 20.0 A"}
    # a held criterion has no margin; the others keep theirs
    assert reasons((40.5, 40.5), None, 20.5, held={"pack_temperature_high"}) == [
        "pack temperature reaches 40.5 °C, above the training flights' 40.0 °C"]
    assert reasons((40.5, 40.5), None, 20.5, held={"current"}) == [
        "sustained current reaches 20.5 A, above the training flights' 20.0 A"]
    # what a log or a vehicle does not measure is not judged
    assert outside_training({"pack_temperature_c": None, "ambient_c": None, "sustained_current_a": None},
                            (90.0, 90.0), (50.0, 50.0), 500.0) == {}


def test_only_fitted_packs_have_an_envelope():
    assert training_envelopes(PROVENANCE) == {"A": TRAINING}
    assert training_envelopes({"source": "paper Tables I and II"}) == {}
    assert training_envelopes(None) == {}
    assert FitEnvelopeWatch({}).update(0.0, ["A", "B"], [20.0, 20.0], 15.0, [0.0, 0.0]) is None


def test_the_sustained_current_is_the_last_minutes_charge():
    watch = FitEnvelopeWatch({"A": TRAINING})
    # 0 A until t = 100 s, then 10 A: the one-minute mean reaches 10 A exactly one minute later
    q, means = 0.0, {}
    for t in range(0, 200):
        q += 10.0 if t > 100 else 0.0
        means[t] = watch.sustained_current("A", float(t), q)
    assert all(means[t] is None for t in range(57))       # under a minute seen: not judged
    assert means[130] == pytest.approx(5.0) and means[159] < 10.0 and means[160] == pytest.approx(10.0)
    # a link silence: the history starts again (a mean across the gap is not a sustained current)
    assert watch.sustained_current("A", 260.0, q + 1000.0) is None
    # message time going backwards (a replay restarted) or a current no longer read: likewise
    assert watch.sustained_current("A", 10.0, 0.0) is None
    assert watch.sustained_current("A", 11.0, None) is None and watch.sustained_current("A", 12.0, 10.0) is None


def fly(watch, temps, amps, air=15.0, t0=0.0, q0=0.0):
    """One status tick a second: pack A at temps[k] °C drawing amps A; the last record."""
    rec, q = None, q0
    for k, temp in enumerate(temps):
        q += amps
        rec = watch.update(t0 + k, ["A", "B"], [temp, 25.0], air, [q, 0.0])
    return rec


def test_a_pack_past_its_training_temperatures_is_said_to_extrapolate_and_cleared_inside():
    watch = FitEnvelopeWatch({"A": TRAINING})
    rec = fly(watch, np.linspace(30.0, 45.0, 90), amps=10.0)
    a = rec["packs"]["A"]
    assert a["state"] == "outside" and rec["outside"] == ["A"] and "B" not in rec["packs"]
    assert a["outside"] == ["pack temperature reaches 45.0 °C, above the training flights' 40.0 °C"]
    assert a["now"]["sustained_current_a"] == pytest.approx(10.0) and a["training"] == TRAINING
    assert "pack A: pack temperature reaches 45.0 °C" in rec["reason"] and "refit" in rec["reason"]
    (banner,) = fit_envelope_warnings(rec)
    assert banner["kind"] == "outside_fit_envelope" and banner["level"] == "warning" and "A" in banner["title"]
    # cooling back to 41 °C: inside the margin but not the span: still outside (no flicker)
    assert fly(watch, [41.0], 10.0, t0=90.0, q0=900.0)["packs"]["A"]["state"] == "outside"
    rec = fly(watch, [39.5], 10.0, t0=91.0, q0=910.0)
    assert rec["packs"]["A"]["state"] == "inside" and rec["outside"] == [] and rec["reason"] is None
    assert fit_envelope_warnings(rec) == []
    # and going up again, it takes the full margin to warn again
    assert fly(watch, [41.5], 10.0, t0=92.0, q0=920.0)["packs"]["A"]["state"] == "inside"


def test_one_criterion_held_does_not_lower_the_others_margins():
    watch = FitEnvelopeWatch({"A": TRAINING})
    # hot, and drawing 20.5 A against the training flights' 20 A (inside the 10 % margin)
    rec = fly(watch, [43.0] * 90, amps=20.5)
    assert rec["packs"]["A"]["outside"] == ["pack temperature reaches 43.0 °C, above the training flights' 40.0 °C"]


def test_a_reading_that_drops_out_keeps_its_last_verdict():
    watch = FitEnvelopeWatch({"A": TRAINING})
    fly(watch, [45.0] * 70, amps=10.0)
    rec = fly(watch, [math.nan] * 3, amps=10.0, t0=70.0, q0=700.0)
    a = rec["packs"]["A"]
    assert a["state"] == "outside" and a["now"]["pack_temperature_c"] is None and "pack temperature" in a["not_judged"]
    assert a["outside"] == ["pack temperature reaches 45.0 °C, above the training flights' 40.0 °C"]
    # back at 41 °C: still past the span, still outside
    assert fly(watch, [41.0], 10.0, t0=73.0, q0=730.0)["packs"]["A"]["state"] == "outside"


def test_a_pack_drawing_more_than_any_training_flight_for_a_minute_is_outside():
    rec = fly(FitEnvelopeWatch({"A": TRAINING}), [25.0] * 90, amps=30.0)
    assert rec["packs"]["A"]["outside"] == ["sustained current reaches 30.0 A, above the training flights' 20.0 A"]


def test_unknown_when_nothing_can_be_judged():
    watch = FitEnvelopeWatch({"A": TRAINING})
    rec = watch.update(0.0, ["A"], [math.nan], None, [None], temperature_modelled=("A",))
    a = rec["packs"]["A"]
    assert a["state"] == "unknown" and a["outside"] == [] and rec["outside"] == []
    assert a["not_judged"] == ["pack temperature", "air temperature", "60-s current"]
    assert a["now"] == {"pack_temperature_c": None, "ambient_c": None, "sustained_current_a": None,
                        "pack_temperature_source": "model"}
    rec = watch.update(1.0, ["A"], [20.0], None, [10.0])
    assert rec["packs"]["A"]["state"] == "inside" and rec["packs"]["A"]["not_judged"] == ["air temperature", "60-s current"]


def test_a_described_vehicle_judges_each_pack_on_the_fit_its_values_come_from(tmp_path):
    from gcs_pdm.models.params import ParameterSet, builtin
    from gcs_pdm.vehicle.description import PackSpec
    from gcs_pdm.vehicle.model_inputs import pack_training_envelope

    base = builtin("previous_si")
    paper_fit = {"training_envelope": TRAINING}
    fitted = ParameterSet(name="fitted", packs=base.packs, motor=base.motor,
                          provenance={"packs": {"LLF20": paper_fit, "ULA20": paper_fit}})
    path = tmp_path / "fitted.json"
    path.write_text(fitted.to_json())

    def spec(pack, scale, capacity_mah=7800.0):
        return PackSpec(name="battery", mavlink_battery_id=0, cells_series=5, capacity_mah=capacity_mah,
                        parameters={"set": str(path), "pack": pack, "scale_to_pack": scale})

    assert pack_training_envelope(spec("LLF20", False)) == TRAINING
    # scaled to a pack twice the paper's 7.8 Ah: the same C-rate is twice the current
    doubled = pack_training_envelope(spec("LLF20", True, capacity_mah=15600.0))
    assert doubled["sustained_current_a"] == pytest.approx(40.0)
    assert doubled["pack_temperature_c"] == TRAINING["pack_temperature_c"]
    assert pack_training_envelope(spec("LRF40", False)) is None          # not fitted
    assert pack_training_envelope(PackSpec(name="b", mavlink_battery_id=0, cells_series=4, capacity_mah=5000)) is None
    # the estimator of a described vehicle: its packs by their own names, each on its reference's fit
    from types import SimpleNamespace

    from gcs_pdm.models.params import PACK_NAMES
    from gcs_pdm.service.fit_envelope import flown_envelopes

    packs = [spec("LLF20", False), spec("LRF40", False).model_copy(update={"name": "other"})]
    described = SimpleNamespace(vehicle=SimpleNamespace(packs=packs), params=None, pack_names=("battery", "other"))
    assert flown_envelopes(described) == {"battery": TRAINING}
    # an estimator flying a parameter set (the paper's aircraft on the active set): its packs by name
    on_set = SimpleNamespace(vehicle=None, params=fitted, pack_names=PACK_NAMES)
    assert flown_envelopes(on_set) == {"LLF20": TRAINING, "ULA20": TRAINING}
    assert flown_envelopes(SimpleNamespace(vehicle=None, params=base, pack_names=PACK_NAMES)) == {}


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


def test_a_learned_set_carries_its_training_envelope_and_warnings(cold_fit, tmp_path):
    from gcs_pdm.fitting.procedure import merge_results
    from gcs_pdm.models.params import ParameterSet, builtin

    merged = merge_results(builtin("previous_si"), {"LLF20": cold_fit})
    prov = ParameterSet.from_json(merged.to_json()).provenance["packs"]["LLF20"]
    assert prov["training_envelope"] == cold_fit.operating_envelope["training"]
    assert prov["training_envelope"]["pack_temperature_c"][1] < 25.0
    assert prov["warnings"] == cold_fit.warnings and any("chen2020_11" in w for w in prov["warnings"])
    assert training_envelopes(merged.provenance) == {"LLF20": prov["training_envelope"]}
    # a vehicle description flies a pack's paper values, which an extended fit did not learn: not judged
    from gcs_pdm.vehicle.description import PackSpec
    from gcs_pdm.vehicle.model_inputs import pack_training_envelope

    assert merged.packs["LLF20"].model == "extended"
    path = tmp_path / "cold.json"
    path.write_text(merged.to_json())
    assert pack_training_envelope(PackSpec(name="b", mavlink_battery_id=0, cells_series=5, capacity_mah=7800,
                                           parameters={"set": str(path), "pack": "LLF20"})) is None


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

    flight = fly_synthetic(true_parameters(), np.random.default_rng(3), duration_s=150.0, initial_soc=0.9)
    frames = sorted(flight.frames, key=lambda fr: fr.time_s)
    half = next(i for i, fr in enumerate(frames) if fr.time_s > 75.0)
    mission = original_mission()

    def start(data_dir):
        svc = Service(load_config(env={}, data_dir=str(data_dir), api_token="fit-envelope-test-token-01", policy="advise"))
        svc.store.save_parameter_set(merge_results(builtin("previous_si"), {"LLF20": cold_fit}, name="cold"))
        return svc

    # the paper's set flown: nothing to compare with, also after the fitted set is activated
    # mid-flight (the filters keep the values they started with until the next start)
    svc = start(tmp_path / "a")
    try:
        loop = LiveLoop(svc, FakeLink(), FakeVehicleMissions(mission.items))
        svc.attach_loop(loop)
        client = TestClient(create_app(svc))
        for fr in frames[:half]:
            loop.process(fr)
        svc.activate_parameter_set("cold")
        for fr in frames[half:]:
            loop.process(fr)
        status = client.get("/status").json()
        assert status["parameter_set"] == "cold" and status["fit_envelope"] is None
        assert "outside_fit_envelope" not in [w["kind"] for w in status.get("warnings", [])]
    finally:
        svc.close()

    # started with the fitted set active: its fitted pack is judged
    svc = start(tmp_path / "b")
    try:
        svc.activate_parameter_set("cold")
        loop = LiveLoop(svc, FakeLink(), FakeVehicleMissions(mission.items))
        svc.attach_loop(loop)
        client = TestClient(create_app(svc))
        for fr in frames:
            loop.process(fr)
        status = client.get("/status").json()
        env = status["fit_envelope"]
        assert set(env["packs"]) == {"LLF20"} and env["outside"] == ["LLF20"]
        llf = env["packs"]["LLF20"]
        assert llf["state"] == "outside" and llf["now"]["pack_temperature_c"] == pytest.approx(
            status["packs"]["LLF20"]["temperature_c"], abs=0.01)
        assert llf["now"]["sustained_current_a"] == pytest.approx(status["packs"]["LLF20"]["current_a"], rel=0.3)
        # the synthetic vehicle flies in 19-20 °C air, the fit's only flight in 6-8 °C air
        assert llf["outside"] == [f"air temperature reaches {llf['now']['ambient_c']:.1f} °C, above the training "
                                  f"flights' {cold_fit.operating_envelope['training']['ambient_c'][1]:.1f} °C"]
        assert abs(llf["now"]["ambient_c"] - status["ambient_c"]) < 1.0
        (banner,) = [w for w in status["warnings"] if w["kind"] == "outside_fit_envelope"]
        assert "LLF20" in banner["title"] and banner["text"] == env["reason"]
    finally:
        svc.close()


def test_the_estimators_default_air_temperature_is_not_a_reading():
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.estimation.synthetic import fly_synthetic
    from gcs_pdm.frames import AmbientFrame, PackFrame
    from gcs_pdm.models.params import builtin
    from gcs_pdm.service.fit_envelope import MAX_GAP_S, estimator_readings
    from gcs_pdm.sim.truth import true_parameters

    frames = sorted(fly_synthetic(true_parameters(), np.random.default_rng(4), duration_s=60.0).frames,
                    key=lambda f: f.time_s)
    est = StateEstimator(builtin("previous_si"))
    for f in frames:
        if not isinstance(f, AmbientFrame):
            est.consume(f)
    readings = estimator_readings(est, est.estimate())
    assert math.isfinite(est.estimate().ambient_c) and readings["ambient_c"] is None
    assert all(q is not None for q in readings["charge_c"])
    est.consume(AmbientFrame(frames[-1].time_s, 17.5))
    assert estimator_readings(est, est.estimate())["ambient_c"] == pytest.approx(17.5, abs=0.5)
    # a pack whose current has not been read for longer than MAX_GAP_S: its charge is not judged
    t_end = frames[-1].time_s + MAX_GAP_S + 1.0
    est.consume(PackFrame(t_end, "LLF20", 20.0, float("nan"), 25.0))
    est.consume(AmbientFrame(t_end, 17.5))
    charge = estimator_readings(est, est.estimate())["charge_c"]
    assert charge[est.pack_names.index("LLF20")] is None
