"""Fault contract, debouncing, and the motor power-loss magnitude against the kernel's fault model."""
import json

import numpy as np
import pytest

from gcs_pdm.diagnosis.debounce import DebounceConfig, Debouncer
from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, PACK_CAPACITY_LOSS, Fault
from gcs_pdm.diagnosis.motor_power import MotorPowerConfig, MotorPowerLossDetector, fault_magnitude
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import default_set
from gcs_pdm.models.powertrain import MotorFault, PowertrainState


def test_fault_dict_is_stable_and_round_trips():
    f = Fault(MOTOR_POWER_LOSS, "aft", 0.42, 612.5, 0.97, {"median_m": np.float64(-0.41), "x": np.arange(2)},
              updated_s=620.0)
    d = f.to_dict()
    assert list(d) == ["type", "component", "magnitude", "time_s", "confidence", "active", "updated_s",
                       "cleared_s", "evidence"]
    json.dumps(d)
    back = Fault.from_dict(d)
    assert back.key == f.key and back.magnitude == 0.42 and back.evidence["x"] == [0, 1]
    assert f.as_motor_fault() == MotorFault("aft", 0.42)
    with pytest.raises(ValueError, match="type"):
        Fault("broken_wing", "vehicle", 1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="confidence"):
        Fault(MOTOR_POWER_LOSS, "fwd", 0.1, 0.0, 1.5)
    with pytest.raises(ValueError, match="MotorFault"):
        Fault(PACK_CAPACITY_LOSS, "LLF20", 0.3, 0.0, 1.0).as_motor_fault()
    with pytest.raises(ValueError, match="missing field"):
        Fault.from_dict({"type": MOTOR_POWER_LOSS})


def test_debouncer_needs_persistence_and_has_hysteresis():
    d = Debouncer(DebounceConfig(raise_after_s=3.0, clear_after_s=5.0))
    # flapping every second never raises
    assert [d.update(t, t % 2 == 0, t % 2 == 1) for t in range(10)] == [None] * 10
    events = [d.update(t, True, False) for t in range(10, 15)]
    assert events == [None, None, None, "raise", None] and d.active
    # neither strong nor gone: stays active
    assert all(d.update(t, False, False) is None for t in range(15, 30)) and d.active
    events = [d.update(t, False, True) for t in range(30, 37)]
    assert events.index("clear") == 5 and not d.active


@pytest.mark.parametrize("motor,m", [("fwd", 0.2), ("aft", 0.5), ("fwd", 0.9), ("aft", 0.0)])
def test_magnitude_from_currents_recovers_the_kernel_fault(motor, m):
    ps = default_set()
    st = PowertrainState.full(ps, soc=0.8)
    fault = np.zeros(2)
    fault[["fwd", "aft"].index(motor)] = m
    n = 50
    run = topology.simulate_powertrain(ps.pack_matrix()[None], ps.motor_vector()[None], st.pack_state[None],
                                     st.motor_temp_c[None], np.ones(n), np.linspace(600, 1800, n), 20.0, fault[None],
                                     record=True)
    for k in (0, n // 2, n - 1):
        # the kernel computes motor current from the voltage at the start of the step
        v = run.pack_voltage[0, k - 1] if k else kernel.terminal_voltage(ps.pack_matrix(), st.pack_state)
        i = run.motor_current[0, k]
        signed, p0, p1 = fault_magnitude(i[0], i[1], v[0] + v[2], v[1] + v[3], ps.motor_vector())
        expect = m if motor == "fwd" else -m
        assert signed == pytest.approx(expect, abs=1e-6)


def test_detector_ignores_spikes_and_low_power():
    det = MotorPowerLossDetector(default_set().motor_vector(), MotorPowerConfig())
    rng = np.random.default_rng(0)
    events = []
    for k in range(400):
        t = 0.5 * k
        i_f, i_a = 12.0 + rng.normal(0, 0.25), 12.0 + rng.normal(0, 0.25)
        if k % 37 == 0:
            i_f += 40.0   # ESC spike
        events += det.update(t, i_f, i_a, 40.0, 40.0)
    assert events == [] and det.samples == 400
    # idling: nothing to say about power share
    assert det.update(300.0, 1.6, 1.0, 40.0, 40.0) == [] and det.low_power_skipped == 1
