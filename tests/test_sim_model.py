"""The steppable simulated vehicle: it flies its mission on the kernel's truth, fails like a real one."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_pdm.missions import same_items
from gcs_pdm.models import kernel
from gcs_pdm.sim.faults import Degradation, parse_fault
from gcs_pdm.sim.model import SimConfig, VehicleModel
from gcs_pdm.sim.record import fly
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.sim.telemetry import TelemetryConfig

SQUARE = mission_from_enu([(1500, 0, 100), (1500, 1500, 150), (0, 1500, 100)])
QUIET = TelemetryConfig(drop_rate=0.0)


def run(model: VehicleModel, max_s: float = 3600.0):
    events = []
    while not model.finished and model.time_s < max_s:
        events += model.step()
    return events


def test_flies_the_mission_in_order_and_lands_at_home():
    m = VehicleModel(SimConfig(mission=tuple(SQUARE)))
    events = run(m)
    reached = [e.seq for e in events if e.kind == "reached"]
    assert reached == [1, 2, 3, 4, 5]
    s = m.state()
    assert s.landed and not s.failed and not s.armed and s.on_ground
    assert math.hypot(s.east_m, s.north_m) < 150.0  # rolled out near home
    # 4 legs of ~1.5 km plus the climb-out: distance over ground within reason
    assert 6000 < s.distance_m < 9000
    assert any(e.kind == "statustext" and e.text == "Landed" for e in events)
    # the packs of one string carry the same current; all four lost charge
    assert np.all(s.pack_soc < 1.0) and np.all(s.pack_soc > 0.7)


def test_truth_is_the_kernel_for_the_same_inputs():
    """Pack voltages of the flight equal simulate_packs fed with the flight's own currents."""
    rec = fly(SimConfig(mission=tuple(SQUARE)), QUIET, truth_every_s=0.1)
    params = SimConfig().truth().pack_matrix()
    t = rec.time_s
    dt = np.diff(np.concatenate([[0.0], t]))
    x0 = kernel.initial_pack_state(params, 1.0, 20.0)
    current = rec.truth["pack_current_a"].T  # (4, n)
    ambient = np.broadcast_to(rec.truth["ambient_c"], current.shape)
    # the current of each tick flows over that tick: the kernel's zero-order hold, per pack
    out = kernel.simulate_packs(params, x0, np.broadcast_to(dt, current.shape), current, ambient)
    np.testing.assert_allclose(out.voltage.T, rec.truth["pack_voltage_v"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(out.temperature.T, rec.truth["pack_temp_c"], rtol=0, atol=1e-9)
    # energy bookkeeping: the motors' electrical energy is what the four packs delivered
    assert rec.final.energy_j == pytest.approx(rec.final.pack_energy_j.sum(), rel=0.01)


def test_motor_fault_between_items_loads_the_healthy_motor():
    cfg = SimConfig(mission=tuple(SQUARE), faults=(parse_fault("motor:aft:0.8@leg:2-3"),))
    rec = fly(cfg, QUIET)
    assert len(rec.fault_log) == 1
    f = rec.fault_log[0]
    t_reached = dict(rec.reached)
    assert t_reached[2] < f["time_s"] < t_reached[3]
    assert f["current_seq"] == 3 and f["motor"] == "aft"
    t = rec.time_s
    k = int(np.searchsorted(t, f["time_s"]))
    mi = rec.truth["motor_current_a"]
    # same flight condition a few seconds either side: the fwd motor takes over the aft one's share
    assert mi[k + 3, 0] > 1.5 * mi[k - 3, 0]
    assert mi[k + 3, 1] < 0.5 * mi[k - 3, 1]
    share_before = mi[k - 60:k - 1, 0] / mi[k - 60:k - 1].sum(axis=1)
    share_after = mi[k + 1:k + 60, 0] / mi[k + 1:k + 60].sum(axis=1)
    np.testing.assert_allclose(share_before, 0.5, atol=0.01)
    assert np.all(share_after > 0.75)
    # against the same flight without the fault: the healthy motor runs hotter, the faulted one cooler
    base = fly(SimConfig(mission=tuple(SQUARE)), QUIET)
    n = min(len(base.time_s), len(t))
    np.testing.assert_allclose(base.time_s[:n], t[:n])
    mt, mt0 = rec.truth["motor_temp_c"], base.truth["motor_temp_c"]
    np.testing.assert_allclose(mt[:k - 1], mt0[:k - 1])
    assert mt[k + 120, 0] > mt0[k + 120, 0] + 1.0
    assert mt[k + 120, 1] < mt0[k + 120, 1] - 0.3
    assert not rec.failed


def test_time_and_waypoint_triggers():
    cfg = SimConfig(mission=tuple(SQUARE), faults=(parse_fault("motor:fwd:0.3@t:100"), parse_fault("motor:aft:0.5@wp:4")))
    m = VehicleModel(cfg)
    run(m)
    by_motor = {f["motor"]: f for f in m.fault_log}
    arm_t = cfg.start_delay_s
    assert by_motor["fwd"]["time_s"] == pytest.approx(arm_t + 100.0, abs=0.25)
    assert by_motor["aft"]["time_s"] == pytest.approx(dict(m.reached_log)[4], abs=1e-9)
    np.testing.assert_allclose(m.fault, [0.3, 0.5])


def test_too_long_a_mission_for_a_degraded_vehicle_ends_in_a_reported_failure():
    far = mission_from_enu([(4000, 0, 150), (4000, 4000, 150), (0, 4000, 150), (4000, 0, 150), (0, 4000, 150)])
    cfg = SimConfig(mission=tuple(far), initial_soc=0.45, degradations=(Degradation("LRF40", 0.7, 1.5),),
                    faults=(parse_fault("motor:aft:0.8@leg:2-3"),))
    m = VehicleModel(cfg)
    events = run(m, max_s=7200)
    s = m.state()
    assert s.failed and ("cut-off" in s.failure or "depleted" in s.failure)
    texts = [e.text for e in events if e.kind == "statustext"]
    assert any(t.startswith("FAILURE:") for t in texts)
    assert s.on_ground and not s.armed and not s.landed
    reached = [e.seq for e in events if e.kind == "reached"]
    assert len(far) - 1 not in reached  # never got to land
    # after the failure nothing flows: the vehicle stopped
    assert np.all(s.motor_current_a == 0.0) and s.groundspeed_mps == 0.0


def test_same_seed_same_flight_other_seed_other_noise(tmp_path):
    short = mission_from_enu([(800, 0, 80)])
    a = fly(SimConfig(mission=tuple(short), seed=3), None, tmp_path / "a.tlog")
    b = fly(SimConfig(mission=tuple(short), seed=3), None, tmp_path / "b.tlog")
    c = fly(SimConfig(mission=tuple(short), seed=4), None, tmp_path / "c.tlog")
    assert (tmp_path / "a.tlog").read_bytes() == (tmp_path / "b.tlog").read_bytes()
    assert (tmp_path / "a.tlog").read_bytes() != (tmp_path / "c.tlog").read_bytes()
    # noise differs, physics does not
    np.testing.assert_array_equal(a.truth["pack_voltage_v"], c.truth["pack_voltage_v"])


def test_new_mission_in_flight_keeps_the_current_index_or_takes_the_named_one():
    m = VehicleModel(SimConfig(mission=tuple(SQUARE)))
    while m.current_seq < 3:
        m.step()
    other = mission_from_enu([(-1000, 0, 120), (-1000, -1000, 120), (0, -1000, 120)])
    m.set_mission(other)
    assert m.current_seq == 3 and same_items(m.mission, other)
    m.set_mission(other, current=2)
    assert m.current_seq == 2
    events = run(m)
    assert [e.seq for e in events if e.kind == "reached"] == [2, 3, 4, 5]


def test_clearing_the_mission_in_flight_returns_home_and_lands():
    m = VehicleModel(SimConfig(mission=tuple(SQUARE)))
    while m.current_seq < 3:
        m.step()
    m.clear_mission()
    assert m.mode == "RTL"
    run(m)
    s = m.state()
    assert s.landed and math.hypot(s.east_m, s.north_m) < 200.0


def test_bad_initial_soc_is_refused():
    with pytest.raises(ValueError, match="initial_soc"):
        VehicleModel(SimConfig(initial_soc=1.5))
    with pytest.raises(ValueError, match="dt"):
        VehicleModel(SimConfig()).step(0.0)


def test_a_failure_on_the_take_off_roll_stops_the_vehicle_on_the_ground():
    m = VehicleModel(SimConfig(mission=tuple(SQUARE), initial_soc=0.004))
    events = run(m, max_s=600)
    s = m.state()
    assert s.failed and s.on_ground and not s.armed and m.finished
    assert s.time_s < 60  # it never got going
    assert [e.seq for e in events if e.kind == "reached"] == []
    assert any(e.kind == "statustext" and e.text.startswith("FAILURE:") for e in events)
