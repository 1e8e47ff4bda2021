"""The service's hand-offs: typed faults end to end and one prediction path."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, PACK_CAPACITY_LOSS, Fault, motor_faults, operator_fault
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
from gcs_pdm.estimation.synthetic import fly_synthetic
from gcs_pdm.models.powertrain import MotorFault, fault_vector
from gcs_pdm.service import adapters
from gcs_pdm.sim.truth import true_parameters


def test_motor_faults_are_the_worst_active_power_loss_per_motor():
    faults = [Fault(MOTOR_POWER_LOSS, "aft", 0.4, 10.0, 0.9), operator_fault("aft", 0.7, 12.0),
              operator_fault("fwd", 0.2, None), Fault(MOTOR_POWER_LOSS, "fwd", 0.9, 5.0, 0.9, active=False),
              Fault(PACK_CAPACITY_LOSS, "LLF20", 0.3, 1.0, 1.0)]
    assert motor_faults(faults) == [MotorFault("aft", 0.7), MotorFault("fwd", 0.2)]
    declared = operator_fault("fwd", 0.2, None)
    assert declared.confidence == 1.0 and math.isnan(declared.time_s)


def test_prediction_job_is_predict_from_estimator_on_a_copy():
    truth = true_parameters()
    flight = fly_synthetic(truth, np.random.default_rng(3), duration_s=120.0, initial_soc=0.9)
    est = StateEstimator(truth)
    for fr in flight.frames:
        est.consume(fr)
    assert est.ready()
    faults = [MotorFault("aft", 0.3)]
    job = adapters.prediction_job(est, 900.0, 15.0, faults, seed=7, n_samples=16)
    for fr in flight.frames[:5]:  # the filters moving on must not change the queued prediction
        est.consume(fr)
    got = job()
    est2 = StateEstimator(truth)
    for fr in flight.frames:
        est2.consume(fr)
    want = predict_from_estimator(est2, FutureLoad.constant(900.0, 3600.0, 10.0, 15.0), rng=np.random.default_rng(7),
                                  n_samples=16, fault=fault_vector(faults), trajectories=False, stop_on_failure=False)
    assert np.allclose(got.pack_time_to_cutoff_s, want.pack_time_to_cutoff_s, equal_nan=True)


def test_active_faults_are_the_diagnosers_typed_faults():
    class Diagnoser:
        def active_faults(self):
            return [Fault(MOTOR_POWER_LOSS, "aft", 0.4, 10.0, 0.9)]

    (f,) = adapters.active_faults(Diagnoser())
    assert isinstance(f, Fault) and f.key == (MOTOR_POWER_LOSS, "aft")
    with pytest.raises(AttributeError):
        adapters.active_faults(object())
