"""Exact search against brute force; the particle filter (Algorithm 1) and the stronger planner."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.models import kernel
from gcs_pdm.models.params import builtin
from gcs_pdm.planning.exact import brute_force, exact_search
from gcs_pdm.planning.local_search import improve, neighbours, pf_local_search
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.scenario import Scenario, Waypoint
from gcs_pdm.planning.simulator import VehicleSimulator, original_order
from gcs_pdm.sim.truth import true_parameters

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "scenarios"


def load(n):
    return Scenario.from_json((FIXTURES / f"table3_{n}.json").read_text())


def random_instance(seed, n=6, hot=False):
    """A random small field around the Table III start, same vehicle and fault; ``hot``: tall climbs
    and a pack temperature limit that binds before the energy does."""
    base = load(7)
    rng = np.random.default_rng(seed)
    alts = [50.0, 300.0, 600.0] if hot else [80.0, 120.0, 200.0]
    wps = tuple(Waypoint(i + 1, float(rng.uniform(-5000, 5000)), float(rng.uniform(-5000, 5000)),
                         float(rng.choice(alts)), float(rng.integers(5, 90))) for i in range(n))
    sc = dataclasses.replace(base, waypoints=wps, name=f"random_{seed}")
    if hot:
        sc = dataclasses.replace(sc, limits=dataclasses.replace(sc.limits, pack_max_temp_c=31.0))
    return sc


@pytest.mark.parametrize("case", ["t7-truth", "t8-prior", "r1", "r2", "r3", "h1", "h2"])
def test_exact_matches_brute_force(case):
    if case.startswith("t"):
        sc = load(int(case[1]))
        ps = true_parameters() if case.endswith("truth") else builtin("previous_si")
    else:
        sc, ps = random_instance(int(case[1:]), hot=case[0] == "h"), builtin("paper_si")
    sim = VehicleSimulator.for_scenario(sc, ps)
    ex = exact_search(sim)
    bf = brute_force(sim)
    assert ex.stats["proven_optimal"]
    assert ex.reward == bf.reward
    assert ex.objective == pytest.approx(bf.objective, abs=1e-9)
    assert ex.feasible and bf.feasible
    # and without dominance pruning or warm start
    assert exact_search(sim, dominance=False, warm_start=False).reward == bf.reward
    if case[0] == "h":  # the temperature limit is what stops the longer routes
        ev = sim.evaluate([tuple(range(len(sc.waypoints)))])
        assert ev.cause[0] == kernel.FAIL_PACK_OVERTEMP


def test_exact_beats_the_original_order_which_fails():
    sc = load(10)
    sim = VehicleSimulator.for_scenario(sc, true_parameters())
    assert not sim.evaluate([original_order(sc)]).feasible[0]
    ex = exact_search(sim)
    assert ex.feasible and ex.reward > 0 and 0 < len(ex.route) < len(sc.waypoints)


def test_interrupted_exact_returns_a_feasible_route_and_says_so():
    sim = VehicleSimulator.for_scenario(load(10), true_parameters())
    calls = iter(range(100))
    ex = exact_search(sim, should_stop=lambda: next(calls) >= 2)
    assert not ex.stats["proven_optimal"] and ex.feasible and len(ex.route) <= 2


def test_particle_filter_is_seeded_and_reproducible():
    sim = VehicleSimulator.for_scenario(load(10), builtin("paper_si"))
    a = particle_filter(sim, particles=20, seed=7)
    b = particle_filter(sim, particles=20, seed=7)
    assert a.route == b.route and a.reward == b.reward
    routes = {particle_filter(sim, particles=5, seed=s).route for s in range(8)}
    assert len(routes) > 1


@pytest.mark.parametrize("n", [7, 8, 9, 10])
def test_particle_filter_never_returns_an_infeasible_route_as_feasible(n):
    sim = VehicleSimulator.for_scenario(load(n), builtin("previous_si"))
    opt = exact_search(sim).reward
    rewards = []
    for seed in range(10):
        p = particle_filter(sim, particles=10, seed=seed)
        again = sim.evaluate([p.route])
        assert p.feasible == bool(again.feasible[0]) and p.feasible
        assert p.reward == again.reward[0] <= opt
        rewards.append(p.reward)
    assert np.mean(rewards) > 0.7 * opt  # K = 10: a sanity floor, not a quality claim


def test_particle_filter_deadline_returns_the_best_so_far():
    sim = VehicleSimulator.for_scenario(load(10), builtin("paper_si"))
    stop_now = particle_filter(sim, particles=30, seed=0, should_stop=lambda: True)
    assert stop_now.route == () and stop_now.stats["interrupted"] and stop_now.feasible
    calls = iter(range(100))
    one = particle_filter(sim, particles=30, seed=0, should_stop=lambda: next(calls) >= 1)
    assert one.stats["iterations"] == 1 and one.feasible and len(one.route) >= 1


def test_theta_steers_the_particle_filter():
    sim = VehicleSimulator.for_scenario(load(9), builtin("paper_si"))
    frugal = [particle_filter(sim, particles=20, seed=s, theta=(0.0, 0.0, 1.0)) for s in range(3)]
    greedy = [particle_filter(sim, particles=20, seed=s) for s in range(3)]
    # a weight that only counts energy keeps short routes (each particle is still weighed by its
    # longest feasible extension, as Algorithm 1 has it)
    assert max(p.power_cost_mj for p in frugal) < min(p.power_cost_mj for p in greedy)
    assert max(p.reward for p in frugal) < min(p.reward for p in greedy)


def test_neighbourhood_moves():
    moves = neighbours((0, 1), 3)
    assert (0, 1, 2) in moves and (2, 0, 1) in moves  # insert
    assert (0, 2) in moves and (2, 1) in moves         # replace
    assert (1, 0) in moves                             # swap / relocate / 2-opt
    assert (0, 1) not in moves
    assert all(len(set(m)) == len(m) for m in moves)


def test_local_search_climbs_from_nothing_to_a_feasible_route():
    sim = VehicleSimulator.for_scenario(load(8), builtin("paper_si"))
    route, reward, _, flown = improve(sim, ())
    assert reward > 0 and flown > 1 and sim.evaluate([route]).feasible[0]


@pytest.mark.parametrize("n", [7, 10])
def test_stronger_planner_reaches_the_optimum(n):
    sim = VehicleSimulator.for_scenario(load(n), true_parameters())
    opt = exact_search(sim)
    for seed in range(3):
        p = pf_local_search(sim, particles=30, seed=seed)
        assert p.feasible and p.reward >= 0.995 * opt.reward


def test_chosen_route_completes_on_the_truth():
    """Where the original order fails, the route planned on a model flies home on the true vehicle."""
    sc = load(10)
    truth_sim = VehicleSimulator.for_scenario(sc, true_parameters())
    assert truth_sim.evaluate([original_order(sc)]).fail_leg[0] >= 0
    p = pf_local_search(VehicleSimulator.for_scenario(sc, builtin("paper_si")), seed=0)
    ev = truth_sim.evaluate([p.route])
    assert ev.fail_leg[0] == -1 and ev.reward_reached[0] == p.reward > 0


def test_beam_search_is_a_feasible_heuristic_and_exact_when_wide():
    sim = VehicleSimulator.for_scenario(load(10), builtin("paper_si"))
    ex = exact_search(sim)
    narrow = exact_search(sim, beam=4, warm_start=False)
    assert narrow.planner == "beam" and not narrow.stats["proven_optimal"]
    assert narrow.feasible and narrow.reward <= ex.reward
    assert exact_search(sim, beam=100_000, warm_start=False).reward == ex.reward


@pytest.mark.parametrize("planner", ["pf", "exact", "pfls", "brute"])
def test_no_waypoints_and_no_way_home(planner):
    from gcs_pdm.planning.planners import plan_scenario

    sc = load(7)
    empty_sc = dataclasses.replace(sc, waypoints=())
    empty = plan_scenario(empty_sc, empty_sc.flown_vehicle(), planner)
    assert empty.route == () and empty.feasible
    dead = dataclasses.replace(sc, start=dataclasses.replace(sc.start, pack_soc=(0.02, 0.5, 0.02, 0.5)))
    p = plan_scenario(dead, dead.flown_vehicle(), planner)
    # nothing is reachable: the plan is the way home, reported as infeasible with its cause
    assert p.route == () and not p.feasible and p.failure != "none"
