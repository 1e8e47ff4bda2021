"""Flight power model and the closed-loop powertrain with motor faults."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.models import kernel as K
from gcs_pdm.models import powertrain as PT
from gcs_pdm.models import topology as TOPO
from gcs_pdm.models.params import default_set

PS = default_set()


def _flight(power_w: float, seconds: int, faults=(), **kw):
    dt = np.ones(seconds)
    dt[0] = 0.0
    return PT.fly(PS, PT.PowertrainState.full(PS, 20.0), dt, np.full(seconds, power_w), 20.0, faults, **kw)


def test_power_model_is_physical():
    cruise = PT.shaft_power(25.0)
    assert 500 < cruise < 1200
    # a lightly loaded aerobatic airframe: minimum-power speed (~12 m/s) sits below its stall
    # speed, so across the flyable envelope faster always costs more
    speeds = np.linspace(PT.EDGE_540.stall_airspeed, PT.EDGE_540.max_airspeed, 57)
    assert np.all(np.diff(PT.shaft_power(speeds)) > 0)
    slow = np.linspace(8, 14, 25)
    assert 10 < slow[np.argmin(PT.shaft_power(slow))] < 14
    assert PT.shaft_power(25.0, 4.0) > 2 * cruise
    assert PT.shaft_power(25.0, -4.0) < cruise
    assert PT.shaft_power(25.0, 0.0, PT.air_density(2000.0)) != pytest.approx(cruise)
    assert 3000 < PT.shaft_rpm(cruise) < 5000


def test_cruise_and_climb_pack_currents_are_realistic():
    cruise = _flight(float(PT.shaft_power(25.0)), 60)
    i_cruise = cruise.pack_current[0, -1]
    assert np.all((10 < i_cruise) & (i_cruise < 20))
    climb = _flight(float(PT.shaft_power(25.0, 5.0)), 60)
    assert np.all(climb.pack_current[0, -1] > 2 * i_cruise)
    # packs in one string carry the same current; the two strings split the shaft evenly
    np.testing.assert_array_equal(cruise.pack_current[0, :, 0], cruise.pack_current[0, :, 2])
    np.testing.assert_allclose(cruise.motor_current[0, :, 0], cruise.motor_current[0, :, 1], rtol=1e-3)


def test_thirty_minute_cruise_fits_in_a_full_set_of_packs():
    run = _flight(float(PT.shaft_power(25.0)), 1800)
    assert not run.failed[0]
    soc = run.pack_soc[0, -1]
    assert np.all((soc > 0.05) & (soc < 0.5))
    charge = run.charge_c[0]
    dt = np.ones(1800)
    dt[0] = 0.0
    np.testing.assert_allclose(charge, (run.pack_current[0] * dt[:, None]).sum(axis=0), rtol=1e-12)


@pytest.mark.parametrize("m", [0.3, 0.8, 1.0])
def test_motor_fault_shifts_power_to_the_healthy_motor(m):
    power = float(PT.shaft_power(25.0))
    healthy = _flight(power, 30)
    faulted = _flight(power, 30, (PT.MotorFault("aft", m),), fault_drag=0.1)
    motor = PS.motor
    v_fwd = faulted.pack_voltage[0, 0, 0] + faulted.pack_voltage[0, 0, 2]
    v_aft = faulted.pack_voltage[0, 0, 1] + faulted.pack_voltage[0, 0, 3]
    i_fwd, i_aft = faulted.motor_current[0, 1]
    # the faulted rotor's propeller drag and its unpowered friction/core loss load the shaft
    p_tot = power * (1 + 0.5 * 0.1 * m) + m * motor.I_0 * faulted.pack_voltage[0, 0, [1, 3]].sum()
    # recover each motor's shaft power from its electrical input: P = V I - R I^2 - I_0' V
    shaft_fwd = v_fwd * i_fwd - motor.R_w * i_fwd**2 - motor.I_0 * v_fwd
    shaft_aft = v_aft * i_aft - motor.R_w * i_aft**2 - motor.I_0 * (1 - m) * v_aft
    assert shaft_aft == pytest.approx(0.5 * p_tot * (1 - m), rel=2e-3, abs=0.5)
    assert shaft_fwd == pytest.approx(p_tot * (1 + m) / 2, rel=2e-3)
    assert i_fwd > healthy.motor_current[0, 1, 0] * (1 + 0.8 * m)
    # more current, more heat in the healthy motor and its string
    longer_h = _flight(power, 600)
    longer_f = _flight(power, 600, (PT.MotorFault("aft", m),))
    assert longer_f.max_motor_temp[0, 0] > longer_h.max_motor_temp[0, 0] + 1.0
    assert longer_f.max_pack_temp[0, 0] > longer_h.max_pack_temp[0, 0]
    # a fault never makes flying cheaper
    assert longer_f.energy_j[0] > longer_h.energy_j[0]


def test_a_faulted_vehicle_fails_where_a_healthy_one_does_not():
    power = float(PT.shaft_power(25.0))
    healthy = _flight(power, 1500)
    faulted = _flight(power, 1500, (PT.MotorFault("fwd", 0.9),))
    assert not healthy.failed[0]
    assert faulted.failed[0]
    assert faulted.fail_cause[0] in (K.FAIL_UNDERVOLTAGE, K.FAIL_DEPLETED)
    k = faulted.fail_step[0]
    assert np.all(np.isnan(faulted.pack_voltage[0, k + 1:]))
    # the fwd fault loads the aft string (ULA20 + URA40)
    assert min(faulted.pack_voltage[0, k, [1, 3]]) < PT.Limits().pack_cutoff_v or min(faulted.pack_soc[0, k, [1, 3]]) <= 0
    assert faulted.pack_soc[0, k, 0] > 0.3


def test_limits_decide_the_failure_cause():
    power = float(PT.shaft_power(25.0, 3.0))
    hot_motor = _flight(power, 600, limits=PT.Limits(motor_max_temp_c=35.0))
    assert hot_motor.fail_cause[0] == K.FAIL_MOTOR_OVERTEMP
    hot_pack = _flight(power, 600, limits=PT.Limits(pack_max_temp_c=25.0))
    assert hot_pack.fail_cause[0] == K.FAIL_PACK_OVERTEMP
    both_dead = _flight(power, 10, (PT.MotorFault("fwd", 1.0), PT.MotorFault("aft", 1.0)))
    assert both_dead.fail_cause[0] == K.FAIL_POWER


def test_batched_powertrain_equals_single_runs():
    rng = np.random.default_rng(5)
    n_vec, n = 5, 400
    dt = np.ones(n)
    dt[0] = 0
    power = rng.uniform(300, 2500, (n_vec, n))
    faults = rng.uniform(0, 1, (n_vec, 2)) * (rng.uniform(size=(n_vec, 2)) < 0.5)
    x0 = np.stack([K.initial_pack_state(PS.pack_matrix(), rng.uniform(0.5, 1), 20.0) for _ in range(n_vec)])
    tm0 = np.full((n_vec, 2), 20.0)
    run = TOPO.simulate_powertrain(PS.pack_matrix(), PS.motor_vector(), x0, tm0, dt, power, 20.0, faults,
                                record=True)
    for j in range(n_vec):
        one = TOPO.simulate_powertrain(PS.pack_matrix(), PS.motor_vector(), x0[j], tm0[j], dt, power[j], 20.0,
                                    faults[j], record=True)
        np.testing.assert_array_equal(run.pack_voltage[j], one.pack_voltage[0])
        np.testing.assert_array_equal(run.energy_j[j], one.energy_j[0])


def test_motor_thermal_broadcasts_one_parameter_row_over_many_motors():
    m = PS.motor_vector()
    dt = np.ones(3)
    temp = K.simulate_motor_thermal(m, [20.0, 30.0], dt, np.full((2, 3), 10.0), 20.0)
    for j, t0 in enumerate((20.0, 30.0)):
        np.testing.assert_array_equal(temp[j], K.simulate_motor_thermal(m, t0, dt, np.full(3, 10.0), 20.0)[0])


def test_fault_inputs_are_validated():
    with pytest.raises(ValueError, match="magnitude"):
        PT.MotorFault("aft", 1.5)
    with pytest.raises(ValueError, match="motor"):
        PT.MotorFault("left", 0.5)
    np.testing.assert_allclose(PT.fault_vector([PT.MotorFault("aft", 0.5), PT.MotorFault("aft", 0.5)]), [0, 0.75])
