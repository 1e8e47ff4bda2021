"""Issue 32, one vehicle: while discovery has not yet derived a description (``service.vehicle`` is
None), the planner, the route risk and the telemetry intake's count-down all fly the one vehicle
``Service.flown_vehicle`` names (edge540) with the same overrides (the scenario's limits); and the
scenario a plan records reproduces that plan."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from gcs_pdm.geo import geodetic_from_enu
from gcs_pdm.models import kernel
from gcs_pdm.models.powertrain import DescribedMotorFault, MotorFault, PowertrainState
from gcs_pdm.planning.plan import make_plan
from gcs_pdm.planning.scenario import Home, Scenario, ScenarioError, Waypoint
from gcs_pdm.planning.simulator import VehicleSimulator, original_order
from gcs_pdm.planning.table3_scenario import table3_scenario
from gcs_pdm.service import adapters
from gcs_pdm.service.config import load_config
from gcs_pdm.service.decision import Candidate
from gcs_pdm.service.plan_executor import PlanExecutor
from gcs_pdm.service.runtime import Service
from gcs_pdm.sim.truth import true_parameters
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS
from service_stand_ins import FakeLink  # tests/service_stand_ins.py


@pytest.fixture(scope="module")
def discovering(tmp_path_factory):
    """A service with no description yet and the Table III objectives loaded (motors 80 °C, where
    edge540's description says 100 °C; landing reserve 15 %)."""
    svc = Service(load_config(env={}, data_dir=str(tmp_path_factory.mktemp("svc")),
                              api_token="one-vehicle-test-token-0001"))
    scenario = table3_scenario(true_parameters(), 10)
    svc.load_objectives_scenario(scenario)
    executor = PlanExecutor(svc, FakeLink(), None, None, None, None)
    yield svc, executor, scenario
    svc.close()


def test_route_risk_takes_the_limits_the_count_down_takes(discovering, monkeypatch):
    svc, executor, _ = discovering
    assert svc.vehicle is None and svc.limits.motor_max_temp_c == 80.0
    seen = []
    monkeypatch.setattr(adapters, "route_risk", lambda est, load, faults, limits, **kw: seen.append(limits) or {})
    chosen = Candidate("planner", (), True, 0.0, 0.0, 0.0, None, {})
    executor._assess_risk(SimpleNamespace(estimator=object(), faults=(), time_s=0.0), [chosen], chosen,
                          {"planner": object()})
    count_down = svc.limits_override(svc.flown_vehicle())  # what the telemetry intake's prediction takes
    assert seen == [count_down] and count_down == svc.limits.kernel_limits()


def test_the_planner_flies_that_vehicle_and_its_record_reproduces_the_plan(discovering):
    svc, executor, sc = discovering
    flown = executor._flown()
    assert flown["vehicle"] is svc.flown_vehicle() is PRESETS["edge540"]
    assert flown["params"] is svc.params and flown["limits"] == svc.limits
    h = sc.home
    catalogue = executor.catalogue
    position = (*geodetic_from_enu(sc.start.east_m, sc.start.north_m, h.lat_deg, h.lon_deg), sc.start.alt_m)
    state = sc.start.powertrain(svc.params)
    keep = [sc.waypoints[i].number for i in original_order(sc)]
    cands, info = adapters.plan_candidates(state, list(sc.faults), catalogue, (h.lat_deg, h.lon_deg, h.ground_alt_m),
                                           h.ground_temp_c, position, keep, planner=None, particles=10, seed=0,
                                           deadline_s=10.0, time_s=sc.start.time_s, **flown)
    (kept,) = cands
    recorded = Scenario.from_dict(info["scenario"])
    index = {w.number: i for i, w in enumerate(recorded.waypoints)}
    again = make_plan(VehicleSimulator.for_scenario(recorded), [index[n] for n in keep], "keep")
    assert info["vehicle"]["name"] == "edge540" and recorded.limits == svc.limits
    # bit for bit: the service's plan is the scenario file's (the scenario's motor limit, 80 °C, in C_h)
    assert (kept.reward_reached, kept.extra["health_cost"], kept.extra["final_soc"]) == \
        (again.reward_reached, again.health_cost, list(again.final_soc))


def test_a_described_vehicles_live_state_is_recorded_and_is_not_the_scenario_files_vehicle():
    quad = PRESETS["quad-4s"]
    pp = model_inputs(quad).pack_matrix
    state = PowertrainState(kernel.initial_pack_state(pp, 0.7, 25.0), np.full(4, 30.0))
    sc = Scenario.from_live(state, [DescribedMotorFault("m2", 0.3)], [Waypoint(1, 100.0, 0.0, 30.0, 5.0, 8.0)],
                            (0.0, 0.0, 30.0), Home())
    back = Scenario.from_json(sc.to_json())
    np.testing.assert_array_equal(np.array(back.start.pack_state), state.pack_state)
    assert back.start.motor_temp_c == (30.0,) * 4
    with pytest.raises(ScenarioError, match="1 pack.*--vehicle"):
        back.flown_vehicle()
    # flown as the description it is: the recorded state is the simulator's start
    sim = VehicleSimulator(back, quad, state=state, motor_faults={"m2": 0.3})
    assert np.array_equal(sim.initial.pack_state, state.pack_state) and sim.pack_names == quad.pack_names


def test_the_simulator_takes_a_description_not_a_parameter_set():
    sc = table3_scenario(true_parameters(), 7)
    with pytest.raises(TypeError, match="for_scenario"):
        VehicleSimulator(sc, true_parameters())
    with pytest.raises(ValueError, match="no motor 'left'"):
        VehicleSimulator(sc, PRESETS["edge540"], motor_faults={"left": 0.2})
    assert MotorFault("aft", 0.7) in sc.faults and sc.flown_vehicle().motor_faults["aft"] == pytest.approx(0.7)


def test_with_no_scenario_loaded_the_planner_keeps_the_reserve_the_outlook_judges_by(tmp_path):
    """No objectives loaded: edge540 plans on its description's limits and its 15 % landing reserve
    (the outlook's), not on no reserve at all."""
    svc = Service(load_config(env={}, data_dir=str(tmp_path / "svc"), api_token="one-vehicle-test-token-0002"))
    try:
        assert svc.limits is None
        flown = PlanExecutor(svc, FakeLink(), None, None, None, None)._flown()
        assert flown["limits"] is None and flown["vehicle"].landing_reserve == 0.15
        sim = VehicleSimulator(table3_scenario(true_parameters(), 7), **flown)
        assert sim._base_reserve == 0.15
    finally:
        svc.close()
