"""Thin adapters onto the other packages (estimation, diagnosis, planning, fitting).

Everything the service needs from a colleague's package goes through one function here, so a
renamed class or argument is a one-line change in one place. Nothing here holds physics: the
adapters only translate between the service's plain values and the packages' types.
"""
from __future__ import annotations

import copy
import logging
import time
from typing import Any, Callable, Sequence

import numpy as np

from gcs_pdm.diagnosis.faults import Fault
from gcs_pdm.models.params import ParameterSet
from gcs_pdm.models.powertrain import MotorFault, PowertrainState
from gcs_pdm.service.decision import Candidate, CatalogueWaypoint

log = logging.getLogger(__name__)


# --- estimation --------------------------------------------------------------------------------

def make_estimator(vehicle, params: ParameterSet | None = None):
    """The estimator of ``vehicle`` (a ``VehicleDescription``), ``params`` (a parameter set: the
    service's ``parameter_override()``) flown over its values."""
    from gcs_pdm.estimation.estimator import StateEstimator

    return StateEstimator(params, vehicle=vehicle)


def prediction_job(estimator, shaft_power_w: float, ambient_c: float, faults: Sequence[MotorFault], limits=None,
                   *, horizon_s: float = 3600.0, step_s: float = 10.0, n_samples: int = 64, seed: int = 0):
    """A Monte Carlo time-to-cut-off prediction at the present load, as a callable to run elsewhere.

    The estimator is copied here (on the telemetry thread) so the prediction can run on a worker
    while the filters move on; the prediction itself is the estimation package's
    ``predict_from_estimator`` (the diagnoser's prognosis uses the same one, capacity spread included).
    The estimator's vehicle flies its packs and motors (``faults`` by its motor names) with its own
    limits, or ``limits`` (a ``Limits``: the service's ``limits_override()``) for every pack and motor;
    its self-calibrated packs' times to cut-off are their own filters' (``prediction.with_calibrated_cutoffs``)."""
    from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator, with_calibrated_cutoffs
    from gcs_pdm.models.powertrain import fault_vector

    frozen = copy.deepcopy(estimator)
    load = FutureLoad.constant(shaft_power_w, horizon_s, step_s, ambient_c)
    fv = fault_vector(list(faults), estimator.motor_names)

    def run():
        rng = np.random.default_rng(seed)
        pred = predict_from_estimator(frozen, load, rng=rng, n_samples=n_samples, fault=fv, limits=limits,
                                      trajectories=False,
                                      stop_on_failure=False)  # each pack to its own cut-off, not only the first
        # a self-calibrated pack's count-down is its own filter's, as in the held-current prediction
        return with_calibrated_cutoffs(pred, frozen, rng=rng, n_samples=n_samples)

    return run


#: Monte Carlo samples behind a plan's probability of failure (fixed, so a plan record is reproducible)
ROUTE_RISK_SAMPLES = 100


def route_risk(estimator, load, faults: Sequence[MotorFault], limits=None, *, n_samples: int = ROUTE_RISK_SAMPLES,
               seed: int = 0) -> dict:
    """Probability of failure and landing SoC of flying ``load`` (a route's ``FutureLoad``) from a
    frozen estimator, through the estimation package's ``predict_from_estimator`` (state and
    parameter uncertainty, the believed motor faults): one batched call of ``n_samples``.

    Any vehicle: the estimator's vehicle flies its own packs, buses and motors with the
    description's limits (or ``limits``, one for every pack and motor), and ``faults`` name its
    motors (``powertrain.fault_vector``).

    A sample fails if any failure (cut-off, depletion, over-temperature, power) occurs on the way.
    ``landing_soc`` is the lowest pack's SoC at the landing of the samples that land (5/50/95 %
    quantiles; ``None`` when none does: a failed sample has no landing SoC); ``landing_samples``
    says how many they are. Two routes assessed with one ``seed`` start from the same state and
    parameter draws, so their difference is the route's."""
    from gcs_pdm.estimation.prediction import QUANTILES, predict_from_estimator
    from gcs_pdm.models.powertrain import fault_vector

    if n_samples < 1:
        raise ValueError(f"n_samples: must be >= 1, got {n_samples}")
    fv = fault_vector(list(faults), estimator.motor_names)
    p = predict_from_estimator(estimator, load, rng=np.random.default_rng(seed), n_samples=n_samples, fault=fv,
                               limits=limits, trajectories=False, per_sample=True)
    landed = ~np.isfinite(p.sample_failure_time_s)
    soc = p.sample_end_soc[landed]  # (landed samples, packs)

    def q(a):
        a = a[np.isfinite(a)]
        if not a.size:  # never a number that cannot be supported
            return {f"p{round(100 * k):02d}": None for k in QUANTILES}
        return {f"p{round(100 * k):02d}": round(float(v), 4) for k, v in zip(QUANTILES, np.quantile(a, QUANTILES))}

    return {"failure_probability": p.p_failure, "failure_causes": dict(p.failure_causes), "n_samples": n_samples,
            "seed": seed, "landing_samples": int(landed.sum()), "landing_soc": q(soc.min(axis=1)),
            "landing_soc_packs": {n: q(soc[:, i]) for i, n in enumerate(p.pack_names)}}


def cutoff_at_present_draw_job(estimator, vehicle, *, n_samples: int = 64, seed: int = 0):
    """Each pack's Monte Carlo time to its cut-off if it keeps its present draw (any description),
    as a callable to run elsewhere (the estimator is copied here, on the telemetry thread)."""
    from gcs_pdm.estimation.prediction import predict_packs_at_current
    from gcs_pdm.vehicle.model_inputs import model_inputs

    frozen = copy.deepcopy(estimator)
    cutoff = model_inputs(vehicle).pack_cutoff_v
    return lambda: predict_packs_at_current(frozen, cutoff, rng=np.random.default_rng(seed), n_samples=n_samples)


# --- diagnosis ---------------------------------------------------------------------------------

def make_diagnoser(vehicle, params: ParameterSet | None = None, limits=None):
    """The diagnosis pipeline of ``vehicle``: ``.consume(frame)``, ``active_faults()``,
    ``readiness()``; ``params`` flown over its values, ``limits`` (a ``Limits``) for every pack and
    motor in its prognosis (the service's ``parameter_override()``, ``limits_override()``)."""
    from gcs_pdm.replay.vehicle import pipeline_for

    return pipeline_for(vehicle, params, limits=limits)


def estimator_of(diagnoser):
    """The pipeline runs its own state estimator; the service reads that one (one filter, not two)."""
    return getattr(diagnoser, "estimator", None)


def active_faults(diagnoser) -> list[Fault]:
    """The diagnoser's active faults (typed: ``gcs_pdm.diagnosis.faults.Fault``)."""
    return list(diagnoser.active_faults())


# --- planning ----------------------------------------------------------------------------------

def _deadline(deadline_s: float) -> Callable[[], bool]:
    end = time.monotonic() + deadline_s
    return lambda: time.monotonic() > end


def run_planner(name: str, sim, *, particles: int, seed: int, deadline_s: float):
    """The named planner of the registry (``gcs_pdm.planning.planners``; ``auto`` = ``pfls``) on
    ``sim`` within a wall-clock deadline; returns its ``Plan``."""
    from gcs_pdm.planning.planners import run_planner as run

    return run(name, sim, particles=particles, seed=seed, should_stop=_deadline(deadline_s))


def plan_candidates(state: PowertrainState, faults: Sequence[MotorFault], catalogue: Sequence[CatalogueWaypoint],
                    home: tuple[float, float, float], ground_temp_c: float, position: tuple[float, float, float],
                    keep_route: Sequence[int], *, vehicle, planner: str, particles: int, seed: int,
                    deadline_s: float, time_s: float, params: ParameterSet | None = None,
                    visited: Sequence[int] = (), reward_collected: float = 0.0, limits: Any = None,
                    wind_en: tuple[float, float] | None = None, max_failure_probability: float | None = None,
                    risk_samples: int = 200, estimator=None) -> tuple[list[Candidate], dict]:
    """Plan from the live state; evaluate the planner's route, the current one and the way home.

    Each candidate carries the mission that flies it (``extra["mission"]``: items in the planner's
    ArduPilot layout and the item to make current after the upload). ``vehicle``: the description
    flown (the service's entry point resolves "none given" to ``edge540``); ``state`` and ``faults``
    are its packs' and motors'; ``params`` a parameter set flown over its values and ``limits`` (a
    ``PlanLimits``) one limit for every pack and motor plus the landing reserve (the service's
    ``parameter_override`` / ``plan_limits_override``; None: the description's). The scenario
    records the state planned from (``info["vehicle"]`` names the vehicle). ``wind_en``: the wind
    (east, north m/s) every leg is flown in; None (unknown) plans in calm air and says so in
    ``info["wind_unknown"]``. ``max_failure_probability``: plan risk-bounded over ``risk_samples``
    draws of the simulator's packs and motors (the start from ``estimator``'s covariance when given)
    and judge every candidate on the same draws; each candidate's ``extra["risk"]`` holds its
    P(failure) and landing-SoC quantiles."""
    from gcs_pdm.missions import item_to_json
    from gcs_pdm.planning.mission import plan_to_mission
    from gcs_pdm.planning.plan import make_plan
    from gcs_pdm.geo import enu_from_geodetic
    from gcs_pdm.planning.scenario import Home, Scenario, Waypoint, named_motor_faults
    from gcs_pdm.planning.simulator import VehicleSimulator

    lat0, lon0, alt0 = home
    wps = []
    for w in catalogue:
        if w.number in visited:
            continue
        e, n = enu_from_geodetic(w.lat_deg, w.lon_deg, lat0, lon0)
        wps.append(Waypoint(number=w.number, east_m=e, north_m=n, alt_m=w.alt_m, reward=w.reward,
                            airspeed_mps=w.airspeed_mps))
    e, n = enu_from_geodetic(position[0], position[1], lat0, lon0)
    # The ground ambient is what the scenario wants; aloft it follows the lapse rate from there.
    scenario = Scenario.from_live(state, list(faults), wps, (e, n, position[2]),
                                  Home(lat_deg=lat0, lon_deg=lon0, ground_alt_m=alt0, ground_temp_c=ground_temp_c),
                                  limits, params=params, time_s=time_s, reward_collected=reward_collected,
                                  visited=tuple(visited), wind_en_mps=wind_en if wind_en is not None else (0.0, 0.0))
    motor_faults = named_motor_faults(faults, vehicle.motor_names)
    sim = VehicleSimulator(scenario, vehicle, params=params, state=state, motor_faults=motor_faults, limits=limits)
    index_of = {w.number: i for i, w in enumerate(scenario.waypoints)}
    t0 = time.perf_counter()
    judge = sim
    if max_failure_probability is not None:
        from gcs_pdm.planning.risk import RiskSimulator, Uncertainty, draw

        unc = Uncertainty(wind_sd_mps=1.5 if wind_en is not None else 3.0)
        judge = RiskSimulator(sim, draw(sim, risk_samples, uncertainty=unc, seed=seed,
                                        **_estimated_start(estimator, sim)),
                              max_failure_probability=max_failure_probability)
    keep = [index_of[n] for n in keep_route if n in index_of]
    if planner is None:  # the outlook of the current mission only (no planning)
        plans = {"keep": make_plan(judge, keep, "keep")}
        planned = None
    else:
        if judge is not sim:
            from gcs_pdm.planning.planners import resolve, run_risk_bounded

            # the risk search runs Algorithm 1 for "auto"/"pfls": PF + local search over the draws does
            # not fit a replan's budget (20 s on a 10-waypoint field, vs ~1-5 s for the PF)
            name = resolve(planner).name
            planned = run_risk_bounded("pf" if name == "pfls" else name, judge, particles=particles, seed=seed,
                                       should_stop=_deadline(deadline_s))
        else:
            planned = run_planner(planner, sim, particles=particles, seed=seed, deadline_s=deadline_s)
        plans = {"planner": planned, "keep": make_plan(judge, keep, "keep"), "home": make_plan(judge, [], "home")}
    plan_s = time.perf_counter() - t0
    cands = []
    for name, p in plans.items():
        mp = plan_to_mission(scenario, p, airborne=True)
        cands.append(Candidate(
            name=name, route=tuple(p.numbers), feasible=bool(p.feasible), reward=float(p.reward),
            reward_reached=float(p.reward_reached), objective=float(p.objective),
            cause=None if p.feasible else p.failure,
            extra={"flight_time_s": p.flight_time_s, "health_cost": p.health_cost, "power_cost_mj": p.power_cost_mj,
                   "final_soc": list(p.final_soc), "fail_leg": p.fail_leg,
                   "mission": {"items": [item_to_json(i) for i in mp.items], "current_seq": mp.current_seq},
                   **({"risk": judge.risk_of(p.route)} if judge is not sim else {})}))
    info = {"planner": getattr(planned, "planner", planner), "plan_time_s": plan_s, "risk_bounded": judge is not sim, "scenario": scenario.to_dict(),
            "loads": {name: route_load(sim, p.route) for name, p in plans.items()}}
    if wind_en is None:
        info["wind_unknown"] = "no wind estimate: planned in calm air"
    info["vehicle"] = {"name": vehicle.name, "pack_state": np.asarray(state.pack_state).tolist(),
                       "motor_temp_c": np.asarray(state.motor_temp_c).tolist(),
                       "motor_faults": {f.motor: f.magnitude for f in faults}}
    return cands, info


def _estimated_start(estimator, sim) -> dict:
    """The risk draws' start and parameters: the planned state with the estimator's pack covariance
    (plus the capacity mismatch it adds to the SoC spread of a pack it has not calibrated, as the
    prediction does: a self-calibrated pack's σ carries its capacity's uncertainty already), and
    the parameters spread as the estimator knows them (``risk.spread_from_estimator``); without an
    estimator, the prior spread. Any vehicle: the estimator tracks the packs and motors the
    simulator flies, in its order."""
    from gcs_pdm.planning.risk import prior_spread, spread_from_estimator

    if estimator is None:
        return {"spread": prior_spread(len(sim.pack_names))}
    from gcs_pdm.models import kernel

    packs = estimator.packs
    cov = np.array(packs.cov, dtype=np.float64, copy=True)
    soc = kernel.state_of_charge(packs.params, packs.mean)
    calibrated = np.array([c is not None for c in getattr(estimator, "calib", [None] * len(soc))])
    extra = estimator.config.capacity_rel_sigma * np.clip(1.0 - soc, 0.0, 1.0) * packs.params[:, kernel.I_CMAX]
    cov[:, kernel.S_QB, kernel.S_QB] += np.where(calibrated, 0.0, extra) ** 2
    cov *= estimator.prediction_inflation()[:, None, None]
    tm_sd = np.asarray(estimator.motors.temperature()[1], dtype=np.float64)
    return {"pack_mean": np.asarray(sim.initial.pack_state, dtype=np.float64), "pack_cov": cov,
            "motor_sd": np.where(np.isfinite(tm_sd), tm_sd, 2.0), "spread": spread_from_estimator(estimator)}


def route_load(sim, route: Sequence[int]):
    """The shaft-power profile of flying ``route`` then landing, as the estimator's ``FutureLoad``
    (the planner's own leg samples, so prognosis and planning see one future)."""
    from gcs_pdm.estimation.prediction import FutureLoad, load_for_route

    load = load_for_route(sim, [int(r) for r in route])
    # already at the landing site: nothing left to fly, a zero load (never an empty one)
    return load if np.size(load.dt) else FutureLoad(np.zeros(1), np.zeros(1), 20.0)


def set_mission_load(diagnoser, load, start_s: float) -> None:
    """Tell the diagnoser's prognosis what the rest of the flight will ask of the powertrain."""
    fn = getattr(diagnoser, "set_mission", None)
    if fn is not None:
        fn(load, start_s)


# --- simulated vehicle -------------------------------------------------------------------------

def start_sim_vehicle(sim_config, url: str, speedup: float, telemetry=None, hold=None):
    """The loopback simulated vehicle in a background thread, talking MAVLink on ``url``; the
    returned object has ``.stop()``, ``.state`` (the truth) and ``.fault_log``; ``hold()`` True
    stops its clock (``gcs_pdm.sim.vehicle``)."""
    from gcs_pdm.sim.vehicle import SimulatedVehicle

    return SimulatedVehicle(sim_config, url, speedup=speedup, telemetry=telemetry, hold=hold).start()
