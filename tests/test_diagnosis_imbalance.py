"""Motor power loss on a multirotor from the imbalance between ESCs, and the capability statement."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.diagnosis.motor_imbalance import EscImbalanceDetector, motor_diagnosis_capability
from gcs_pdm.diagnosis.motor_power import fault_magnitude
from gcs_pdm.models import kernel, multirotor
from gcs_pdm.models.topology import simulate_vehicle
from gcs_pdm.vehicle.description import from_dict
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS


def _hover(desc, fault, n=400, seed=0):
    inputs = model_inputs(desc)
    a = desc.airframe
    p = multirotor.hover_power(desc.mass_kg, len(desc.motors), a.rotor_diameter_m, a.figure_of_merit)
    x0 = kernel.initial_pack_state(inputs.pack_matrix, 0.9, 25.0)[None]
    run = simulate_vehicle(inputs, None, None, x0, np.full((1, inputs.n_motors), 25.0), np.ones(n), np.full(n, p),
                           20.0, np.asarray(fault)[None], record=True)
    rng = np.random.default_rng(seed)
    currents = run.motor_current[0] + rng.normal(0.0, 0.1, run.motor_current[0].shape)   # ESC noise
    bus = run.pack_voltage[0].mean(axis=1)
    return inputs, currents, bus


@pytest.mark.parametrize("preset, faulted, magnitude", [("quad-4s", 1, 0.3), ("hex-6s", 4, 0.5)])
def test_imbalance_finds_the_faulted_motor_and_its_magnitude(preset, faulted, magnitude):
    desc = PRESETS[preset]
    fault = np.zeros(len(desc.motors))
    fault[faulted] = magnitude
    inputs, currents, bus = _hover(desc, fault)
    det = EscImbalanceDetector(inputs.motor_names, inputs.motor_matrix)
    events = [e for k in range(len(bus)) for e in det.update(float(k), currents[k], bus[k])]
    raised = [f for ev, f in events if ev == "raise"]
    assert [f.component for f in raised] == [inputs.motor_names[faulted]]
    assert det.fault_vector()[faulted] == pytest.approx(magnitude, abs=0.05)


def test_no_fault_no_alarm_and_two_motors_agree_with_the_shaft_formula():
    desc = PRESETS["quad-4s"]
    inputs, currents, bus = _hover(desc, np.zeros(4), seed=1)
    det = EscImbalanceDetector(inputs.motor_names, inputs.motor_matrix)
    assert not [e for k in range(len(bus)) for e in det.update(float(k), currents[k], bus[k])]
    # M = 2: the imbalance formula is the shared-shaft one
    motor = inputs.motor_matrix[0]
    two = EscImbalanceDetector(("fwd", "aft"), np.stack([motor, motor]))
    f = two.magnitudes(np.array([20.0, 35.0]), np.array([40.0, 40.0]))
    m, _, _ = fault_magnitude(20.0, 35.0, 40.0, 40.0, motor)
    assert f[0] == pytest.approx(m, rel=1e-9) and f[1] < 0


def test_capability_says_why_not():
    ok, how = motor_diagnosis_capability(PRESETS["edge540"])
    assert ok and "shaft" in how
    ok, how = motor_diagnosis_capability(PRESETS["quad-4s"])
    assert ok and "imbalance" in how
    ok, why = motor_diagnosis_capability(PRESETS["plane-3s"])
    assert not ok and why.startswith("not diagnosable with this telemetry: one motor")
    data = PRESETS["hex-6s"].to_dict()
    data["motors"][2]["readings"]["current"] = False
    ok, why = motor_diagnosis_capability(from_dict(data))
    assert not ok and "no ESC current from m3" in why


def _quad_in_pipeline(currents_at, seconds=120.0):
    """A quad-4s through the diagnoser at 10 Hz: ``currents_at(t)`` gives the four ESC currents."""
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
    from gcs_pdm.frames import MotorFrame, PackFrame

    desc = PRESETS["quad-4s"]
    pipe = DiagnosisPipeline(vehicle=desc)
    names = [m.name for m in desc.motors]
    for k in range(int(seconds * 10)):
        t = round(0.1 * (k + 1), 2)
        currents = currents_at(t)
        pipe.consume(PackFrame(t, "battery", 15.2, sum(currents), 30.0))
        for n, i in zip(names, currents):
            pipe.consume(MotorFrame(t, n, i, 6000.0, 40.0))
    return pipe, names


def test_a_multirotors_unequal_healthy_shares_are_not_a_fault():
    # centre of gravity a little aft: the rear motors (m2, m4) carry steadily more (15 vs 12.5 A);
    # judged against equal shares that read as a 12 % power loss of both front motors, at confidence 1
    pipe, names = _quad_in_pipeline(lambda t: [12.5, 15.0, 12.5, 15.0])
    assert not [f for f in pipe.faults if f.type == "motor_power_loss"]
    shares = pipe.motor_power.shares
    assert shares is not None and shares[1] > shares[0] and abs(sum(shares) / 4 - 1.0) < 1e-12


def test_a_loss_after_the_shares_are_learned_is_raised_against_the_motors_own_share():
    def currents(t):
        if t < 80.0:
            return [12.5, 15.0, 12.5, 15.0]
        return [13.3, 10.5, 13.3, 16.0]   # m2 loses ~30 % of its share, the others make it up
    pipe, names = _quad_in_pipeline(currents)
    raised = [f for f in pipe.faults if f.type == "motor_power_loss"]
    assert [f.component for f in raised] == ["m2"]
    assert raised[0].time_s > 80.0 and 0.2 < raised[0].magnitude < 0.5
    assert "learned_share" in raised[0].evidence


def test_a_gross_loss_from_take_off_is_raised_while_the_shares_are_learned():
    pipe, names = _quad_in_pipeline(lambda t: [6.0, 15.0, 15.0, 15.0], seconds=20.0)
    assert pipe.motor_power.shares is None  # still learning (its first 60 s with power)
    assert [f.component for f in pipe.faults if f.type == "motor_power_loss"] == ["m1"]


def test_a_loss_raised_while_learning_is_not_learned_away():
    pipe, names = _quad_in_pipeline(lambda t: [6.0, 15.0, 15.0, 15.0], seconds=120.0)
    shares = pipe.motor_power.shares
    assert shares is not None and shares[0] == pytest.approx(1.0)   # the healthy motors' mean share
    active = [f.component for f in pipe.faults if f.type == "motor_power_loss" and f.active]
    assert active == ["m1"]
