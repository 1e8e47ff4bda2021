"""Thin adapters onto the other packages (estimation, diagnosis, planning, fitting).

Everything the service needs from a colleague's package goes through one function here, so a
renamed class or argument is a one-line change in one place. Nothing here holds physics: the
adapters only translate between the service's plain values and the packages' types.
"""
from __future__ import annotations

import logging
import time
from typing import Any, Callable, Sequence

import numpy as np

from gcs_pdm.models.params import ParameterSet
from gcs_pdm.models.powertrain import MotorFault, PowertrainState
from gcs_pdm.service.decision import Candidate, CatalogueWaypoint

log = logging.getLogger(__name__)


# --- estimation --------------------------------------------------------------------------------

def make_estimator(params: ParameterSet):
    from gcs_pdm.estimation.estimator import StateEstimator

    return StateEstimator(params)


# --- diagnosis ---------------------------------------------------------------------------------

def make_diagnoser(params: ParameterSet):
    """The diagnosis pipeline: ``.consume(frame)`` and a list of active faults (``active_faults``)."""
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline

    return DiagnosisPipeline(params)


def estimator_of(diagnoser):
    """The pipeline runs its own state estimator; the service reads that one (one filter, not two)."""
    return getattr(diagnoser, "estimator", None)


def active_faults(diagnoser) -> list[dict]:
    """The diagnoser's active faults as ``Fault.to_dict()`` dicts (type, component, magnitude, ...)."""
    faults = getattr(diagnoser, "active_faults", None)
    if faults is None:
        faults = getattr(diagnoser, "faults")
    if callable(faults):
        faults = faults()
    out = []
    for f in faults:
        d = f.to_dict() if hasattr(f, "to_dict") else dict(f)
        if d.get("active", True):
            out.append(d)
    return out


def motor_faults(fault_dicts: Sequence[dict]) -> list[MotorFault]:
    """The planner's view: one MotorFault per motor power loss (the largest if reported twice)."""
    worst: dict[str, float] = {}
    for d in fault_dicts:
        if d.get("type", d.get("kind")) == "motor_power_loss":
            motor = d.get("component", d.get("target"))
            worst[motor] = max(worst.get(motor, 0.0), float(d["magnitude"]))
    return [MotorFault(m, min(max(v, 0.0), 1.0)) for m, v in sorted(worst.items())]


# --- planning ----------------------------------------------------------------------------------

def _deadline(deadline_s: float) -> Callable[[], bool]:
    end = time.monotonic() + deadline_s
    return lambda: time.monotonic() > end


def run_planner(name: str, sim, *, particles: int, seed: int, deadline_s: float) -> list[int]:
    """The route (indices into ``sim.scenario.waypoints``) of the named planner of gcs_pdm.planning.

    ``auto`` is the strongest planner the package offers (falling back to the exact search)."""
    stop = _deadline(deadline_s)
    if name in ("auto", "stronger"):
        try:
            from gcs_pdm.planning.stronger import stronger_planner
        except ImportError:
            name = "exact"
        else:
            return list(stronger_planner(sim, particles=particles, seed=seed, should_stop=stop).route)
    if name == "pf":
        from gcs_pdm.planning.particle_filter import particle_filter

        return list(particle_filter(sim, particles=particles, seed=seed, should_stop=stop).route)
    if name == "exact":
        from gcs_pdm.planning.exact import exact_search

        return list(exact_search(sim, should_stop=stop).route)
    raise ValueError(f"planner: unknown planner {name!r} (auto, stronger, pf, exact)")


def plan_candidates(params: ParameterSet, state: PowertrainState, faults: Sequence[MotorFault],
                    catalogue: Sequence[CatalogueWaypoint], home: tuple[float, float, float],
                    ground_temp_c: float, position: tuple[float, float, float], keep_route: Sequence[int],
                    *, planner: str, particles: int, seed: int, deadline_s: float, time_s: float,
                    visited: Sequence[int] = (), reward_collected: float = 0.0,
                    limits: Any = None) -> tuple[list[Candidate], dict]:
    """Plan from the live state; evaluate the planner's route, the current one and the way home."""
    from gcs_pdm.planning.scenario import Home, Scenario, Waypoint, enu_from_geodetic
    from gcs_pdm.planning.simulator import FAILURE_NAMES, VehicleSimulator

    lat0, lon0, alt0 = home
    wps = []
    for w in catalogue:
        if w.number in visited:
            continue
        e, n = enu_from_geodetic(w.lat_deg, w.lon_deg, lat0, lon0)
        wps.append(Waypoint(number=w.number, east_m=e, north_m=n, alt_m=w.alt_m, reward=w.reward,
                            airspeed_mps=w.airspeed_mps))
    e, n = enu_from_geodetic(position[0], position[1], lat0, lon0)
    scenario = Scenario.from_live(params, state, list(faults), wps, (e, n, position[2]),
                                  Home(lat_deg=lat0, lon_deg=lon0, ground_alt_m=alt0, ground_temp_c=ground_temp_c),
                                  limits, time_s=time_s, reward_collected=reward_collected, visited=tuple(visited))
    sim = VehicleSimulator(scenario, params)
    index_of = {w.number: i for i, w in enumerate(scenario.waypoints)}
    t0 = time.perf_counter()
    route = run_planner(planner, sim, particles=particles, seed=seed, deadline_s=deadline_s)
    plan_s = time.perf_counter() - t0
    keep = [index_of[n] for n in keep_route if n in index_of]
    routes = {"planner": route, "keep": keep, "home": []}
    ev = sim.evaluate(list(routes.values()))
    obj = ev.objective()
    cands = []
    for b, (name, r) in enumerate(routes.items()):
        cause = None if bool(ev.feasible[b]) else FAILURE_NAMES.get(int(ev.cause[b]), str(int(ev.cause[b])))
        cands.append(Candidate(
            name=name, route=tuple(scenario.waypoints[i].number for i in r), feasible=bool(ev.feasible[b]),
            reward=float(ev.reward[b]), reward_reached=float(ev.reward_reached[b]), objective=float(obj[b]),
            cause=cause, extra={"flight_time_s": float(ev.flight_time_s[b]), "health_cost": float(ev.health_cost[b]),
                                "power_cost_mj": float(ev.power_cost[b]),
                                "final_soc": [float(v) for v in np.asarray(ev.final_soc[b])]}))
    info = {"planner": planner, "plan_time_s": plan_s, "scenario": scenario.to_dict()}
    return cands, info


# --- fitting -----------------------------------------------------------------------------------

def fitting_api():
    """The fitting package's pure API module (``fit_battery``, ``fit_motor``, flight loaders)."""
    import gcs_pdm.fitting as fitting

    return fitting
