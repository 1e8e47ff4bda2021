"""Vehicle simulator: incremental = whole-route flights, coarse step = 1 s verdicts, failures located."""
import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.models import kernel
from gcs_pdm.models.params import builtin
from gcs_pdm.planning.scenario import Scenario, Waypoint
from gcs_pdm.planning.simulator import FAIL_RESERVE, VehicleSimulator, original_order
from gcs_pdm.sim.truth import true_parameters

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "scenarios"


@pytest.fixture(scope="module")
def sc9():
    return Scenario.from_json((FIXTURES / "table3_9.json").read_text())


@pytest.fixture(scope="module")
def sim9(sc9):
    return VehicleSimulator.for_scenario(sc9, true_parameters())


def test_incremental_prefix_flight_equals_whole_route_flight(sim9):
    routes = [(0, 1, 2), (4, 3, 5, 6), (6,), (5, 0, 2, 3, 4)]
    whole = sim9.evaluate(routes)
    for b, r in enumerate(routes):
        st = sim9.start_state(1)
        ok_all = True
        for w in r:
            st, ok = sim9.advance(st, np.array([w]))
            ok_all &= bool(ok[0])
        out = sim9.home(st)
        assert bool(out.feasible[0] and ok_all) == bool(whole.feasible[b])
        if whole.feasible[b]:
            np.testing.assert_allclose(out.final_soc[0], whole.final_soc[b], rtol=0, atol=1e-12)
            assert out.power_cost[0] == pytest.approx(whole.power_cost[b], rel=1e-12)
            assert out.reward[0] == whole.reward[b]
            assert out.health_cost[0] == pytest.approx(whole.health_cost[b], rel=1e-12)


def test_batch_rows_do_not_interact(sim9):
    routes = [(0, 1), (3, 2, 1, 0, 4, 5, 6), ()]
    together = sim9.evaluate(routes)
    for b, r in enumerate(routes):
        alone = sim9.evaluate([r])
        assert alone.final_soc[0].tolist() == together.final_soc[b].tolist()
        assert alone.cause[0] == together.cause[b]


def test_coarse_planning_step_gives_the_1s_verdicts(sim9):
    routes = [r for k in range(2, 6) for r in itertools.permutations(range(7), k)][::3]
    coarse = sim9.evaluate(routes)
    fine = sim9.evaluate(routes, dt_s=1.0)
    assert coarse.feasible.any() and (~coarse.feasible).any()
    # never optimistic: what the planning step calls feasible flies at 1 s too ...
    assert not np.any(coarse.feasible & ~fine.feasible)
    # ... and it gives up at most a sliver at the boundary (the verdict margin)
    assert np.mean(coarse.feasible == fine.feasible) > 0.99
    same = coarse.feasible == fine.feasible
    np.testing.assert_array_equal(coarse.reward[same], fine.reward[same])
    assert np.abs(coarse.final_soc - fine.final_soc).max() < 0.01


def test_original_order_fails_on_every_table3_scenario():
    truth = true_parameters()
    for n in (7, 8, 9, 10):
        sc = Scenario.from_json((FIXTURES / f"table3_{n}.json").read_text())
        ev = VehicleSimulator.for_scenario(sc, truth).evaluate([original_order(sc)])
        assert not ev.feasible[0]
        assert ev.reward[0] == 0.0
        # it fails in the air (energy), not just on the reserve, and we know on which leg
        assert ev.cause[0] in (kernel.FAIL_DEPLETED, kernel.FAIL_UNDERVOLTAGE)
        assert 0 <= ev.fail_leg[0] <= n - 2
        assert ev.reached[0] == ev.fail_leg[0]
        reached = [sc.waypoints[i].reward for i in original_order(sc)[:ev.reached[0]]]
        assert ev.reward_reached[0] == sum(reached)


def test_reserve_is_a_failure_at_landing(sc9):
    sim = VehicleSimulator.for_scenario(sc9, true_parameters())
    ev = sim.evaluate([(5, 3, 6)])
    assert ev.feasible[0]
    strict = dataclasses.replace(sc9, limits=dataclasses.replace(sc9.limits,
                                                                 landing_reserve_soc=ev.final_soc[0].min() + 0.01))
    ev2 = VehicleSimulator.for_scenario(strict, true_parameters()).evaluate([(5, 3, 6)])
    assert not ev2.feasible[0] and ev2.cause[0] == FAIL_RESERVE and ev2.fail_leg[0] == -1
    assert ev2.reward[0] == 0 and ev2.reward_reached[0] == ev.reward[0]


def test_motor_temperature_limit_is_located_on_the_leg(sc9):
    hot = dataclasses.replace(sc9, limits=dataclasses.replace(sc9.limits, motor_max_temp_c=sc9.start.motor_temp_c[0] + 4))
    ev = VehicleSimulator.for_scenario(hot, true_parameters()).evaluate([(0, 1, 2)])
    assert ev.cause[0] == kernel.FAIL_MOTOR_OVERTEMP and ev.fail_leg[0] == 0 and ev.reward_reached[0] == 0


def test_fault_loads_the_healthy_string(sc9):
    healthy = dataclasses.replace(sc9, faults=())
    route = [(5, 3, 6)]
    faulted = VehicleSimulator.for_scenario(sc9, builtin("paper_si")).evaluate(route)
    ok = VehicleSimulator.for_scenario(healthy, builtin("paper_si")).evaluate(route)
    assert faulted.feasible[0] and ok.feasible[0]
    # the healthy (fwd) string carries more than its half: it lands far emptier than the aft one,
    # and emptier than it would on a healthy vehicle
    assert faulted.final_soc[0, 0] < faulted.final_soc[0, 1] - 0.2
    assert faulted.final_soc[0, 0] < ok.final_soc[0, 0] - 0.1
    assert abs(ok.final_soc[0, 0] - ok.final_soc[0, 1]) < 0.05


def test_airspeed_optimisation_lowers_energy(sc9):
    ps = builtin("paper_si")
    nominal = VehicleSimulator.for_scenario(sc9, ps)
    tuned = VehicleSimulator.for_scenario(sc9, ps, optimise_airspeed=True)
    route = [(0, 2, 4, 6)]
    assert tuned.evaluate(route).power_cost[0] < nominal.evaluate(route).power_cost[0]
    assert np.all(tuned.legs.airspeed[tuned.legs.duration_s > 0] != 0)


def test_bad_route_is_rejected(sim9):
    with pytest.raises(ValueError, match="distinct waypoint indices"):
        sim9.evaluate([(0, 0)])
    with pytest.raises(ValueError, match="distinct waypoint indices"):
        sim9.evaluate([(99,)])


def test_steep_leg_spirals_at_the_climb_rate(sc9):
    tall = dataclasses.replace(sc9, waypoints=(Waypoint(1, sc9.start.east_m + 100.0, sc9.start.north_m, sc9.start.alt_m + 1000.0, 1.0),))
    sim = VehicleSimulator.for_scenario(tall, builtin("paper_si"))
    assert sim.legs.duration_s[sim.start_node, 0] == pytest.approx(1000.0 / tall.max_climb_rate_mps)


def test_planned_routes_hold_at_1s():
    """The routes the planners choose at the 10 s step keep their verdict flown at 1 s."""
    from gcs_pdm.planning.exact import exact_search
    from gcs_pdm.planning.particle_filter import particle_filter

    for n in (8, 10):
        sc = Scenario.from_json((FIXTURES / f"table3_{n}.json").read_text())
        sim = VehicleSimulator.for_scenario(sc, builtin("paper_si"))
        routes = [exact_search(sim).route] + [particle_filter(sim, particles=10, seed=s).route for s in range(3)]
        coarse, fine = sim.evaluate(routes), sim.evaluate(routes, dt_s=1.0)
        assert coarse.feasible.all() and fine.feasible.all()
        np.testing.assert_array_equal(coarse.reward, fine.reward)
