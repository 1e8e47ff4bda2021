"""Issue 32, item 1: one vehicle, one path. The estimator, the diagnoser and the prediction take a
vehicle description plus an optional parameter set flown over its values; what differs between
vehicles is data (the description's airframe, telemetry and ``current_references``), not a branch on
the paper's aircraft. docs/notes/2026-11-27-one-vehicle.md."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gcs_pdm.diagnosis.motor_imbalance import EscImbalanceDetector, NoMotorDiagnosis
from gcs_pdm.diagnosis.motor_power import MotorPowerLossDetector
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad, predict
from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES, default_set, extended_default
from gcs_pdm.models.powertrain import PowertrainState
from gcs_pdm.vehicle.description import VehicleError
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS


def _with_extended(ps, pack):
    return ps.with_pack(pack, dataclasses.replace(ps.packs[pack], model="extended", extended=extended_default()))


def test_a_parameter_set_overrides_the_descriptions_values_by_pack_name():
    edge = PRESETS["edge540"]
    own, flown = model_inputs(edge), model_inputs(edge, default_set())
    assert np.array_equal(own.pack_matrix, flown.pack_matrix) and np.array_equal(own.motor_matrix, flown.motor_matrix)
    assert not own.from_parameter_set and flown.from_parameter_set and flown.extended_packs == {}
    # a changed pack moves that pack's row only; the layout and limits stay the description's
    lrf = default_set().packs["LRF40"]
    ps = default_set().with_pack("LRF40", dataclasses.replace(lrf, battery=dataclasses.replace(lrf.battery, R_s=0.5)))
    moved = model_inputs(edge, ps)
    assert moved.pack_matrix[2, kernel.I_RS] == 0.5
    assert np.array_equal(np.delete(moved.pack_matrix, 2, axis=0), np.delete(own.pack_matrix, 2, axis=0))
    assert np.array_equal(moved.pack_cutoff_v, own.pack_cutoff_v)
    mixed = model_inputs(edge, _with_extended(default_set(), "ULA20"))
    assert list(mixed.extended_packs) == [PACK_NAMES.index("ULA20")]
    with pytest.raises(VehicleError, match="no pack battery of vehicle 'quad-4s'"):
        model_inputs(PRESETS["quad-4s"], default_set())


def test_a_set_flown_over_a_description_is_never_self_calibrated_and_keeps_its_extended_packs():
    quad = PRESETS["quad-4s"]
    assert all(c is not None for c in StateEstimator(vehicle=quad).calib)  # the description's own: calibrated
    ps = _with_extended(default_set(), "ULA20")
    est = StateEstimator(ps, vehicle=PRESETS["edge540"])
    assert est.calib == [None] * 4 and est.ext_row == {PACK_NAMES.index("ULA20"): 0}


@pytest.mark.parametrize("preset, detector", [("edge540", MotorPowerLossDetector), ("quad-4s", EscImbalanceDetector),
                                              ("plane-3s", NoMotorDiagnosis)])
def test_the_motor_detector_follows_the_airframe_and_telemetry(preset, detector):
    assert type(DiagnosisPipeline(vehicle=PRESETS[preset]).motor_power) is detector


def test_a_shared_shaft_needs_two_motors():
    edge = PRESETS["edge540"]
    three = edge.model_copy(update={"motors": [*edge.motors, edge.motors[0].model_copy(update={"name": "mid",
                                                                                                 "esc_index": 2})],
                                       "buses": [edge.buses[0], edge.buses[1].model_copy(update={
                                           "motors": ["aft", "mid"]})]})
    with pytest.raises(ValueError, match="motors on one shaft are diagnosed in pairs"):
        DiagnosisPipeline(vehicle=three)


@pytest.mark.parametrize("references, replaced", [(1, True), (2, False)])
def test_current_references_say_how_many_readings_overrule_a_packs_own(references, replaced):
    """One string-mate's reading replaces a pack's outlying current when the description says one
    reference suffices (``edge540``), not when it asks for two (the default)."""
    desc = PRESETS["edge540"].model_copy(update={"current_references": references})
    est = StateEstimator(vehicle=desc)
    est.consume(PackFrame(0.0, "LRF40", 20.0, 30.0, 25.0))  # LLF20's string-mate reads 30 A
    est.consume(PackFrame(0.5, "LLF20", 20.0, 90.0, 25.0))  # LLF20 reads 90 A
    assert est.counters["current_spikes"] == int(replaced)
    assert est.latest_pack_current(0) == (30.0 if replaced else 90.0)


def test_motors_of_one_parameter_vector_share_each_samples_draw():
    """The prediction draws one vector per motor type (as the planner's risk draws do): the two
    motors of the paper's set fly the same sample, a description's differing motors their own."""
    inputs = model_inputs(PRESETS["edge540"])
    st = PowertrainState.full(default_set(), 25.0, 0.9)
    load = FutureLoad.constant(3000.0, 600.0, 10.0, 25.0)
    args = (st.pack_state, np.tile(np.eye(4) * 1e-6, (4, 1, 1)), st.motor_temp_c, np.zeros(2), load)
    one_type = predict((inputs.pack_matrix, inputs.motor_matrix), *args, rng=np.random.default_rng(3), n_samples=16,
                       trajectories=False, vehicle=inputs)
    as_vector = predict(default_set(), *args, rng=np.random.default_rng(3), n_samples=16, trajectories=False)
    assert np.array_equal(one_type.pack_time_to_cutoff_s, as_vector.pack_time_to_cutoff_s)
    assert np.array_equal(one_type.peak_motor_temp_c, as_vector.peak_motor_temp_c)
    two_types = inputs.motor_matrix.copy()
    two_types[1, 0] *= 1.5  # the aft motor's winding resistance: another type
    other = predict((inputs.pack_matrix, two_types), *args, rng=np.random.default_rng(3), n_samples=16,
                    trajectories=False, vehicle=inputs)
    assert not np.array_equal(other.peak_motor_temp_c, as_vector.peak_motor_temp_c)
