"""One entry point over the planners, for the CLI and the service."""
from __future__ import annotations

from typing import Callable, Sequence

from gcs_pdm.models.params import ParameterSet
from gcs_pdm.planning.exact import brute_force, exact_search
from gcs_pdm.planning.local_search import pf_local_search
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.plan import Plan
from gcs_pdm.planning.scenario import Scenario
from gcs_pdm.planning.simulator import DEFAULT_DT_S, DEFAULT_THETA, VehicleSimulator

PLANNERS = ("pf", "exact", "pfls", "brute")


def plan_scenario(scenario: Scenario, planner: str = "pfls", *, params: ParameterSet | None = None,
                  particles: int = 30, seed: int = 0, theta: Sequence[float] = DEFAULT_THETA,
                  dt_s: float = DEFAULT_DT_S, optimise_airspeed: bool = False,
                  should_stop: Callable[[], bool] | None = None, vehicle=None,
                  motor_faults: dict[str, float] | None = None) -> Plan:
    """Plan ``scenario`` with the named planner on ``params`` (default: the scenario's own set), or
    on a vehicle description (``vehicle``, with ``motor_faults`` by its motor names)."""
    sim = VehicleSimulator(scenario, params, dt_s=dt_s, optimise_airspeed=optimise_airspeed, vehicle=vehicle,
                           motor_faults=motor_faults)
    if planner == "pf":
        return particle_filter(sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop)
    if planner == "pfls":
        return pf_local_search(sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop)
    if planner == "exact":
        return exact_search(sim, theta=theta, should_stop=should_stop)
    if planner == "brute":
        return brute_force(sim, theta=theta)
    raise ValueError(f"planner: expected one of {PLANNERS}, got {planner!r}")
