"""The topology powertrain (any description) against the paper's four-pack kernel, and on other vehicles."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.models import kernel, multirotor, topology
from gcs_pdm.models.params import default_set
from gcs_pdm.models.powertrain import Limits
from gcs_pdm.models.topology import simulate_vehicle
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS

FIELDS = ("final_pack_state", "final_motor_temp", "min_pack_voltage", "max_pack_temp", "max_motor_temp", "charge_c",
          "energy_j", "fail_step", "fail_cause", "elapsed_s", "pack_voltage", "pack_current", "pack_temp", "pack_soc",
          "motor_current", "motor_temp")


@pytest.mark.parametrize("fault", [None, [[0.0, 0.0], [0.7, 0.0], [0.0, 0.4], [0.5, 0.5], [1.0, 1.0]]])
def test_edge540_reproduces_the_paper_kernel(fault):
    inputs = model_inputs(PRESETS["edge540"])
    ps = default_set()
    rng = np.random.default_rng(3)
    n_vec = 5
    x0 = np.stack([kernel.initial_pack_state(ps.pack_matrix(), s, 25.0) for s in rng.uniform(0.3, 1.0, n_vec)])
    tm0 = np.full((n_vec, 2), 30.0)
    n = 900
    dt = np.full(n, 2.0)
    power = 1500.0 + 800.0 * np.sin(np.arange(n) / 40.0)
    power[::97] = -50.0
    old = topology.simulate_powertrain(ps.pack_matrix()[None], ps.motor_vector()[None], x0, tm0, dt, power, 20.0, fault,
                                     limits=Limits().as_tuple(), stop_on_failure=True, record=True)
    new = simulate_vehicle(inputs, None, None, x0, tm0, dt, power, 20.0, fault, stop_on_failure=True, record=True)
    assert old.failed.any()                  # the comparison covers failures too
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(new, name), getattr(old, name), err_msg=name)


def test_quad_hovers_on_one_pack_and_a_lost_rotor_loads_the_others():
    desc = PRESETS["quad-4s"]
    inputs = model_inputs(desc)
    a = desc.airframe
    hover = multirotor.hover_power(desc.mass_kg, 4, a.rotor_diameter_m, a.figure_of_merit)
    x0 = kernel.initial_pack_state(inputs.pack_matrix, 1.0, 25.0)[None]
    n = 1200
    healthy = simulate_vehicle(inputs, None, None, x0, np.full((1, 4), 25.0), np.ones(n), np.full(n, hover), 20.0,
                               record=True)
    faulted = simulate_vehicle(inputs, None, None, x0, np.full((1, 4), 25.0), np.ones(n), np.full(n, hover), 20.0,
                               np.array([[0.5, 0.0, 0.0, 0.0]]), record=True)
    i = healthy.motor_current[0, 10]
    assert np.allclose(i, i[0])                                     # symmetric hover
    # the single pack carries the four motors' current
    np.testing.assert_allclose(healthy.pack_current[0, :, 0], healthy.motor_current[0].sum(axis=1))
    # a 20-minute hover on a 5 Ah pack at ~10 A (136 W shaft at 14-16 V plus motor losses): about
    # two thirds of the charge
    assert 9.0 < healthy.pack_current[0, 10, 0] < 12.0
    assert 0.15 < healthy.pack_soc[0, -1, 0] < 0.45
    fi = faulted.motor_current[0, 10]
    assert fi[0] < i[0] < fi[1] and np.allclose(fi[1:], fi[1])   # the imbalance the diagnoser looks for
    assert faulted.energy_j[0] > healthy.energy_j[0]


def test_parallel_packs_share_the_current():
    inputs = model_inputs(PRESETS["hex-6s"])
    x0 = kernel.initial_pack_state(inputs.pack_matrix, 1.0, 25.0)[None]
    run = simulate_vehicle(inputs, None, None, x0, np.full((1, 6), 25.0), np.ones(60), np.full(60, 1500.0), 20.0,
                           record=True)
    np.testing.assert_allclose(run.pack_current[0, :, 0], run.pack_current[0, :, 1])
    np.testing.assert_allclose(2 * run.pack_current[0, :, 0], run.motor_current[0].sum(axis=1))


@pytest.mark.parametrize("stop_on_failure", [False, True])
def test_pack_ends_peaks_and_sparse_record_match_the_full_record(stop_on_failure):
    """What the Monte Carlo reads without a full record: each pack's end (first sample below its
    cut-off or empty) and the energy it delivered up to it, the peaks up to the first failure, and
    ``record_at``'s samples — all equal to what the full per-step record gives."""
    ps = default_set()
    rng = np.random.default_rng(8)
    n_vec = 6
    x0 = np.stack([kernel.initial_pack_state(ps.pack_matrix(), s, 25.0) for s in rng.uniform(0.15, 0.6, n_vec)])
    tm0 = np.full((n_vec, 2), 30.0)
    n = 1500
    dt = np.ones(n)
    dt[0] = 0.0
    power = 1200.0 + 400.0 * np.sin(np.arange(n) / 50.0)
    limits = (19.5, 60.0, 200.0)
    kw = dict(limits=limits, stop_on_failure=stop_on_failure)
    full = topology.simulate_powertrain(ps.pack_matrix()[None], ps.motor_vector()[None], x0, tm0, dt, power, 20.0,
                                        record=True, **kw)
    steps = np.arange(0, n, 7)
    sparse = topology.simulate_powertrain(ps.pack_matrix()[None], ps.motor_vector()[None], x0, tm0, dt, power, 20.0,
                                          record_at=steps, **kw)
    assert full.failed.all() and (full.pack_end_step >= 0).any()
    assert (full.pack_end_step < 0).any() == stop_on_failure  # flown on, every pack reaches its end
    np.testing.assert_array_equal(sparse.recorded_steps, steps)
    for name in ("pack_voltage", "pack_soc", "pack_temp", "motor_temp"):
        np.testing.assert_array_equal(getattr(sparse, name), getattr(full, name)[:, steps], err_msg=name)
    for name in ("pack_end_step", "pack_end_energy_j", "peak_pack_temp_to_failure", "peak_motor_temp_to_failure",
                 "fail_step", "final_pack_state"):
        np.testing.assert_array_equal(getattr(sparse, name), getattr(full, name), err_msg=name)
    ended = (full.pack_voltage < limits[0]) | (full.pack_soc <= 0.0)
    power_w = np.nan_to_num(full.pack_voltage * full.pack_current) * dt[None, :, None]
    for j in range(n_vec):
        last = full.fail_step[j]
        for b in range(4):
            k_end = int(np.argmax(ended[j, :, b])) if ended[j, :, b].any() else -1
            assert full.pack_end_step[j, b] == k_end
            upto = k_end if k_end >= 0 else n - 1
            assert full.pack_end_energy_j[j, b] == pytest.approx(power_w[j, :upto + 1, b].sum(), rel=1e-12)
            assert full.peak_pack_temp_to_failure[j, b] == full.pack_temp[j, :last + 1, b].max()
        assert np.array_equal(full.peak_motor_temp_to_failure[j], full.motor_temp[j, :last + 1].max(axis=0))
    with pytest.raises(ValueError, match="record_at"):
        topology.simulate_powertrain(ps.pack_matrix()[None], ps.motor_vector()[None], x0, tm0, dt, power, 20.0,
                                     record_at=[5, 3], **kw)


def test_read_only_inputs_reuse_the_compiled_driver():
    """A read-only array (a ``broadcast_to`` view, a frozen table) is another numba type: before
    ``kernel.owned`` it compiled the vehicle driver a second time (minutes of CPU, four CI timeouts)
    in a planner's airspeed optimisation and a calibrated pack's route risk. One version serves both."""
    from gcs_pdm.models import lanes

    inputs = model_inputs(PRESETS["quad-4s"])
    x0 = kernel.initial_pack_state(inputs.pack_matrix, 1.0, 25.0)[None]
    n = 20

    def frozen(a):
        a = np.array(a, dtype=np.float64)
        a.setflags(write=False)
        return a

    writable = simulate_vehicle(inputs, None, None, x0, np.full((1, 4), 25.0), np.ones(n), np.full(n, 300.0), 20.0,
                                np.zeros((1, 4)))
    versions = len(lanes._simulate.signatures)
    read_only = simulate_vehicle(inputs, None, frozen(inputs.motor_matrix[None]), frozen(x0),
                                 np.broadcast_to(25.0, (1, 4)), frozen(np.ones(n)), frozen(np.full(n, 300.0)),
                                 20.0, np.broadcast_to(0.0, (1, 4)))
    assert len(lanes._simulate.signatures) == versions
    np.testing.assert_array_equal(read_only.final_pack_state, writable.final_pack_state)
