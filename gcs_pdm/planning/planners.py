"""The planner registry: every planner by name, with its aliases. The CLI (``gcs-pdm plan
--planner``), the service's adapter and the service's configuration all read this one table.

Adding a planner: write ``my_planner(sim, *, particles, seed, theta, should_stop) -> Plan`` (or
wrap it), add one :class:`PlannerEntry` to ``REGISTRY``; the CLI's choices and the service's
accepted ``planner`` values follow.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable, Sequence

from gcs_pdm.planning.plan import Plan
from gcs_pdm.planning.risk import RiskSimulator, draw, plan_risk_bounded
from gcs_pdm.planning.scenario import FlownVehicle, Scenario
from gcs_pdm.planning.simulator import DEFAULT_DT_S, DEFAULT_THETA, VehicleSimulator

StopCheck = Callable[[], bool]

# The modules, not their functions (the package re-exports a function named ``particle_filter``):
# the registry looks each planner up at call time, so a replaced one (a test's spy) is the one run.
exact, local_search, particle_filter = (importlib.import_module(f"gcs_pdm.planning.{m}")
                                        for m in ("exact", "local_search", "particle_filter"))


@dataclass(frozen=True)
class PlannerEntry:
    name: str
    run: Callable[..., Plan]   # (sim, *, particles, seed, theta, should_stop) -> Plan
    summary: str
    live: bool = True          # fast enough for the service's replans (brute force is not)


REGISTRY: dict[str, PlannerEntry] = {e.name: e for e in (
    PlannerEntry("pf", lambda sim, *, particles, seed, theta, should_stop: particle_filter.particle_filter(
        sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop),
        "the paper's Algorithm 1"),
    PlannerEntry("exact", lambda sim, *, particles, seed, theta, should_stop: exact.exact_search(
        sim, theta=theta, should_stop=should_stop),
        "branch and bound"),
    PlannerEntry("pfls", lambda sim, *, particles, seed, theta, should_stop: local_search.pf_local_search(
        sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop),
        "PF + local search (the stronger planner)"),
    PlannerEntry("brute", lambda sim, *, particles, seed, theta, should_stop: exact.brute_force(sim, theta=theta),
        "every ordered subset (small scenarios only)", live=False),
)}

#: other names for a planner: ``auto`` is the strongest one the package offers
ALIASES = {"auto": "pfls", "stronger": "pfls"}

#: every planner name (the CLI's choices)
PLANNERS = tuple(REGISTRY)
#: the names the service accepts (``planner`` setting): aliases first, then the live planners
SERVICE_PLANNERS = (*ALIASES, *(name for name, e in REGISTRY.items() if e.live))


def resolve(name: str) -> PlannerEntry:
    """The planner called ``name`` (an alias resolves to its planner)."""
    entry = REGISTRY.get(ALIASES.get(name, name))
    if entry is None:
        raise ValueError(f"planner: expected one of {(*ALIASES, *REGISTRY)}, got {name!r}")
    return entry


def run_planner(name: str, sim: VehicleSimulator, *, particles: int = 30, seed=0,
                theta: Sequence[float] = DEFAULT_THETA, should_stop: StopCheck | None = None) -> Plan:
    """Run the named planner (or alias) on ``sim``."""
    return resolve(name).run(sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop)


def run_risk_bounded(name: str, sim: RiskSimulator, **kw) -> Plan:
    """The named planner (or alias) with the risk-aware objective on ``sim`` (``risk.plan_risk_bounded``)."""
    return plan_risk_bounded(resolve(name).run, sim, **kw)


def plan_scenario(scenario: Scenario, flown: FlownVehicle, planner: str = "pfls", *, particles: int = 30,
                  seed: int = 0, theta: Sequence[float] = DEFAULT_THETA, dt_s: float = DEFAULT_DT_S,
                  optimise_airspeed: bool = False, should_stop: StopCheck | None = None,
                  max_failure_probability: float | None = None, risk_samples: int = 200) -> Plan:
    """Plan ``scenario`` flown by ``flown`` (``scenario.flown_vehicle(params)``: the scenario file's
    own vehicle, the paper's aircraft; or a description with its state and motor faults) with the
    named planner; the CLI's entry (the service builds its simulator itself:
    ``service.adapters.plan_candidates``).

    ``max_failure_probability`` ε: plan risk-bounded (``planning.risk``: expected reward subject to
    P(failure) <= ε and the reserve at the 5 % quantile, over ``risk_samples`` draws about the
    scenario); None: the deterministic planner on the nominal model (the paper's Table III)."""
    entry = resolve(planner)
    sim = VehicleSimulator(scenario, **flown.simulator_args(), dt_s=dt_s, optimise_airspeed=optimise_airspeed)
    if max_failure_probability is not None:
        risk = RiskSimulator(sim, draw(sim, risk_samples, seed=seed), max_failure_probability=max_failure_probability)
        return plan_risk_bounded(entry.run, risk, particles=particles, seed=seed, theta=theta,
                                 should_stop=should_stop)
    return entry.run(sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop)
