"""Decision maker: the vehicle simulator, the particle-filter planner, the exact search, the stronger
planner (PF + local search) and the mission they produce. See docs/planning.md.

Typical use (the CLI; the service does the same through ``gcs_pdm.service.adapters.plan_candidates``,
which builds the ``VehicleSimulator`` itself and calls ``planners.run_planner``)::

    scenario = Scenario.from_json(text)        # or Scenario.from_live(state, faults, ...)
    plan = plan_scenario(scenario, scenario.flown_vehicle(), "pfls")   # any name of REGISTRY or ALIASES
    mission = plan_to_mission(scenario, plan, airborne=True)   # items + the seq to set current
"""
from gcs_pdm.planning.exact import brute_force, exact_search
from gcs_pdm.planning.local_search import pf_local_search
from gcs_pdm.planning.mission import MissionPlan, plan_to_mission
from gcs_pdm.planning.particle_filter import particle_filter
from gcs_pdm.planning.plan import Plan
from gcs_pdm.planning.planners import PLANNERS, plan_scenario
from gcs_pdm.planning.scenario import Home, PlanLimits, Scenario, ScenarioError, StartState, Waypoint
from gcs_pdm.planning.simulator import FlightState, Outcome, RouteEvaluation, VehicleSimulator

__all__ = [
    "PLANNERS", "FlightState", "Home", "MissionPlan", "Outcome", "Plan", "PlanLimits", "RouteEvaluation", "Scenario",
    "ScenarioError", "StartState", "VehicleSimulator", "Waypoint", "brute_force", "exact_search", "particle_filter",
    "pf_local_search", "plan_scenario", "plan_to_mission",
]
