"""The diagnosis pipeline on seeded synthetic flights: detection, magnitude, no false alarms."""
import json

import numpy as np
import pytest

from gcs_pdm.diagnosis.faults import (DEGRADATION_RATE_DEVIATION, MOTOR_POWER_LOSS, PACK_CAPACITY_LOSS,
                                      PACK_RESISTANCE_RISE, PREDICTED_LIMIT_VIOLATION)
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.diagnosis.prognosis import PrognosisConfig
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.estimation.synthetic import PackDegradation, fly_synthetic
from gcs_pdm.models.params import default_set
from gcs_pdm.sim.truth import true_parameters


def diagnose(flight, mission=True):
    p = DiagnosisPipeline(default_set())
    if mission:
        p.set_mission(FutureLoad(np.diff(flight.time_s, prepend=flight.time_s[0]), flight.shaft_power_w,
                                 float(np.mean(flight.ambient_c))), flight.time_s[0])
    for fr in flight.frames:
        p(fr)
    return p


def raised(p, ftype):
    return [f for f in p.faults if f.type == ftype]


@pytest.mark.parametrize("seed,motor,m", [(21, "fwd", 0.3), (22, "aft", 0.6)])
def test_motor_fault_detected_fast_with_its_magnitude(seed, motor, m):
    flight = fly_synthetic(true_parameters(), np.random.default_rng(seed), duration_s=700.0,
                           fault_motor=motor, fault_magnitude=m, fault_time_s=350.0)
    p = diagnose(flight)
    motor_faults = raised(p, MOTOR_POWER_LOSS)
    assert len(motor_faults) == 1, [f.to_dict() for f in p.faults]
    f = motor_faults[0]
    assert f.component == motor and f.active
    assert 0.0 < f.time_s - flight.fault_time_s < 10.0
    assert f.magnitude == pytest.approx(m, abs=0.03)
    assert f.confidence > 0.9
    assert not raised(p, PACK_CAPACITY_LOSS) and not raised(p, PACK_RESISTANCE_RISE)
    report = json.loads(json.dumps(p.report()))
    assert report["faults"][0]["type"] == MOTOR_POWER_LOSS and report["faults"][0]["time_s"] == pytest.approx(f.time_s, abs=1e-3)
    assert any(e["event"] == "raise" and e["type"] == MOTOR_POWER_LOSS for e in report["events"])


def test_fault_free_noisy_flight_raises_nothing():
    flight = fly_synthetic(true_parameters(), np.random.default_rng(23), duration_s=1200.0, initial_soc=0.9)
    p = diagnose(flight)
    assert p.faults == [], [f.to_dict() for f in p.faults]
    assert p.estimator.estimate().counters["voltage_gated"] > 0  # it did see spikes


def test_pack_degradation_detected_on_the_right_pack_with_an_estimate():
    truth = true_parameters()
    flight = fly_synthetic(truth, np.random.default_rng(24), duration_s=900.0,
                           degradation=(PackDegradation("URA40", capacity=0.65),
                                        PackDegradation("LLF20", resistance=2.5)))
    p = diagnose(flight, mission=False)
    cap = raised(p, PACK_CAPACITY_LOSS)
    res = raised(p, PACK_RESISTANCE_RISE)
    assert [f.component for f in cap] == ["URA40"] and [f.component for f in res] == ["LLF20"]
    model = default_set().pack_matrix()
    flown = flight.truth.pack_matrix()
    true_loss = 1.0 - flown[3, 6] / model[3, 6]        # C_b against the parameter set's
    assert cap[0].magnitude == pytest.approx(true_loss, abs=0.08)
    true_rise = (flown[0, 0] + flown[0, 2]) / (model[0, 0] + model[0, 2]) - 1.0
    assert res[0].magnitude == pytest.approx(true_rise, rel=0.3)
    assert not raised(p, MOTOR_POWER_LOSS)
    assert p.report()["prognosis"]["skipped_no_mission"] > 0


def test_infeasible_mission_after_a_fault_is_predicted_and_the_rate_deviation_fires():
    flight = fly_synthetic(true_parameters(), np.random.default_rng(25), duration_s=1500.0, initial_soc=0.7,
                           fault_motor="fwd", fault_magnitude=0.9, fault_time_s=300.0)
    p = diagnose(flight)
    limit = raised(p, PREDICTED_LIMIT_VIOLATION)
    assert limit and limit[0].time_s > flight.fault_time_s
    assert flight.info["failed_at_s"] is not None and limit[0].time_s < flight.info["failed_at_s"] - 120
    assert raised(p, DEGRADATION_RATE_DEVIATION)
    assert raised(p, MOTOR_POWER_LOSS)[0].component == "fwd"
    # most checks re-used a prediction that still held; the report says how old the latest is
    prog = json.loads(json.dumps(p.report()))["prognosis"]
    assert 1 <= prog["runs"] < prog["reused"], prog
    assert prog["age_s"] == pytest.approx(p.estimator.time_s - prog["predicted_at_s"], abs=1e-3)
    cfg = PrognosisConfig()
    assert 0.0 <= prog["age_s"] <= cfg.max_age_s + cfg.check_every_s and prog["latest"]["p_failure"] > 0.5
    assert "prediction_age_s" in limit[0].evidence


def test_recorded_fault_flight_replays_to_its_fault():
    """The simulated vehicle's recording (fixtures/flights, manifest truth) through the real replay path."""
    from pathlib import Path

    from gcs_pdm.mavlink.replay import replay_tlog

    root = Path(__file__).resolve().parent.parent / "fixtures" / "flights"
    manifest = json.loads((root / "manifest.json").read_text())
    flight = next(f for f in manifest["flights"] if f["name"] == "fault_01")
    injected = flight["faults"][0]
    p = DiagnosisPipeline(default_set())
    summary = replay_tlog(root / flight["tlog"], frame_consumer=p)
    assert [f["type"] for f in summary.faults] == [MOTOR_POWER_LOSS]
    f = summary.faults[0]
    assert f["component"] == injected["motor"]
    assert f["magnitude"] == pytest.approx(injected["magnitude"], abs=0.02)
    # frame time holds the last timed message (up to 5 s here), so allow that much before onset
    assert -5.0 <= f["time_s"] - injected["time_s"] < 15.0


def test_disordered_and_malformed_frames_do_not_break_the_pipeline():
    from gcs_pdm.frames import AmbientFrame, MotorFrame, PackFrame

    flight = fly_synthetic(true_parameters(), np.random.default_rng(26), duration_s=400.0)
    frames = list(flight.frames)
    rng = np.random.default_rng(0)
    # swap neighbours here and there, and sprinkle junk
    for k in rng.choice(len(frames) - 1, size=200, replace=False):
        frames[k], frames[k + 1] = frames[k + 1], frames[k]
    frames.insert(500, PackFrame(float("nan"), "LLF20", 20.0, 10.0, 25.0))
    frames.insert(600, MotorFrame(100.0, "middle", 10.0, 4000.0, 30.0))
    frames.insert(700, AmbientFrame(100.0, None))
    p = DiagnosisPipeline(default_set())
    for fr in frames:
        p(fr)
    c = p.estimator.estimate().counters
    assert c["out_of_order"] > 0 and c["unknown_motor"] == 1
    assert p.faults == []
    e = p.estimator.estimate()
    k = min(int(np.searchsorted(flight.time_s, e.time_s)), flight.time_s.size - 1)
    assert np.all(np.abs(e.soc - flight.soc[k]) < 3 * e.soc_sd)
