"""The planner's vehicle simulator flies a vehicle description: its packs, topology, airframe power."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.models import multirotor
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.scenario import Home, Scenario, StartState, Waypoint
from gcs_pdm.planning.simulator import FAIL_RESERVE, VehicleSimulator, original_order
from gcs_pdm.vehicle.presets import PRESETS


def _scenario(scale_m: float, airspeed: float) -> Scenario:
    # a pentagon of goals; the StartState's four-pack fields are the paper's format and unused here
    angles = np.linspace(0.0, 2 * np.pi, 6)[:-1]
    wps = tuple(Waypoint(i + 1, scale_m * np.cos(a), scale_m * np.sin(a), 40.0, reward=10.0 * (i + 1),
                         airspeed_mps=airspeed) for i, a in enumerate(angles))
    start = StartState(0.0, 0.0, 40.0, pack_temp_c=(20.0,) * 4, motor_temp_c=(20.0,) * 2, pack_soc=(1.0,) * 4)
    return Scenario(name="vehicle", home=Home(), start=start, waypoints=wps, return_airspeed_mps=airspeed,
                    max_climb_rate_mps=2.5)


def test_quad_flies_with_momentum_theory_power_and_its_own_reserve():
    quad = PRESETS["quad-4s"]
    near = VehicleSimulator(_scenario(600.0, 8.0), vehicle=quad)
    a = quad.airframe
    # a level leg's power is the momentum-theory power at its airspeed
    leg = near.legs.power[near.start_node, 0, 0]
    expected = multirotor.shaft_power(8.0, 0.0, quad.mass_kg, 4, a.rotor_diameter_m, a.figure_of_merit,
                                      a.drag_area_m2, a.tip_speed_mps, float(near.legs.power[0, 1, 0] * 0 + 1.225))
    assert leg == pytest.approx(float(expected), rel=0.02)   # density at 40 m vs sea level
    ev = near.evaluate([original_order(near.scenario)])
    assert ev.feasible[0] and ev.final_soc.shape == (1, 1) and ev.final_motor_temp.shape == (1, 4)
    assert 0.25 < ev.final_soc[0, 0] < 0.95
    # three times as far: the 5 Ah pack cannot keep its 25 % landing reserve on the whole tour
    far = VehicleSimulator(_scenario(1800.0, 8.0), vehicle=quad)
    whole = far.evaluate([original_order(far.scenario)])
    assert not whole.feasible[0]
    plan = particle_filter(far, particles=20, seed=1)
    assert plan.feasible and 0 < len(plan.route) < 5 and plan.reward > 0
    assert list(plan.to_dict()["final_motor_temp_c"]) == ["m1", "m2", "m3", "m4"]
    assert list(plan.to_dict()["final_soc"]) == ["battery"]


def test_a_motor_fault_costs_energy_and_unknown_motors_are_refused():
    quad = PRESETS["quad-4s"]
    sc = _scenario(600.0, 8.0)
    route = [original_order(sc)]
    healthy = VehicleSimulator(sc, vehicle=quad).evaluate(route)
    faulted = VehicleSimulator(sc, vehicle=quad, motor_faults={"m2": 0.5}).evaluate(route)
    assert faulted.power_cost[0] > healthy.power_cost[0]
    with pytest.raises(ValueError, match="no motor 'fwd'"):
        VehicleSimulator(sc, vehicle=quad, motor_faults={"fwd": 0.5})


def test_single_battery_plane_uses_its_drag_polar_and_cutoff():
    plane = PRESETS["plane-3s"]
    sim = VehicleSimulator(_scenario(3000.0, 20.0), vehicle=plane)
    assert sim.airframe.mass_kg == plane.mass_kg and sim.airframe.wing_area_m2 == plane.airframe.wing_area_m2
    ev = sim.evaluate([original_order(sim.scenario)])
    assert ev.final_soc.shape == (1, 1)
    assert ev.feasible[0] or ev.cause[0] == FAIL_RESERVE
    # the 3S pack's cut-off (10.5 V), not the paper's 17.5 V, decides undervoltage
    assert sim._topology.pack_cutoff_v[0] == pytest.approx(10.5 + 0.02)


def test_plan_cli_takes_a_vehicle(tmp_path, capsys):
    import json

    from gcs_pdm.cli import main

    path = tmp_path / "quad.json"
    path.write_text(_scenario(1800.0, 8.0).to_json())
    assert main(["plan", str(path), "--vehicle", "quad-4s", "--planner", "pf", "--particles", "10", "--json",
                 "--motor-fault", "m2=0.3"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["feasible"] and list(out["final_soc"]) == ["battery"]
    assert main(["plan", str(path), "--vehicle", "quad-4s", "--motor-fault", "fwd=0.3"]) == 2
    assert "no motor 'fwd'" in capsys.readouterr().err  # docs/cli.md: errors on stderr
