"""`gcs-pdm plan SCENARIO.json` and `gcs-pdm experiment table3|scenarios` (shell over the planning core)."""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

log = logging.getLogger(__name__)

DEFAULT_LEARNED = Path("fixtures/params/learned_sim.json")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plan", description="Plan the best route for SCENARIO.json (format: docs/planning.md).")
    p.add_argument("scenario", type=Path, help="scenario JSON file")
    from gcs_pdm.planning.planners import ALIASES, REGISTRY

    p.add_argument("--planner", choices=(*REGISTRY, *ALIASES), default="pfls",
                   help="; ".join([f"{e.name} = {e.summary}" for e in REGISTRY.values()]
                                  + [f"{a} = {n}" for a, n in ALIASES.items()]))
    p.add_argument("--particles", type=int, default=30, help="particles K (pf, pfls)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dt", type=float, default=10.0, help="planning sample length, s")
    p.add_argument("--optimise-airspeed", action="store_true", help="choose each leg's airspeed for least energy")
    p.add_argument("--risk", type=float, default=None, metavar="EPS",
                   help="risk-bounded: the most expected reward with P(failure) <= EPS and the landing reserve at "
                        "the 5%% quantile, over --samples draws of state, parameters, fault and wind "
                        "(docs/planning.md); default: deterministic, on the nominal model")
    p.add_argument("--samples", type=int, default=200, help="draws of the risk-bounded planner")
    p.add_argument("--deadline", type=float, default=None, help="stop searching after this many seconds")
    p.add_argument("--mission", type=Path, default=None, help="also write the mission (QGC WPL 110) here")
    p.add_argument("--on-ground", action="store_true", help="mission starts with the take-off (default: airborne)")
    p.add_argument("--json", action="store_true", help="print the plan as JSON")
    p.add_argument("--vehicle", default=None, metavar="FILE|PRESET",
                   help="plan for a vehicle description (docs/vehicles.md): its packs, topology, airframe power, "
                        "limits and reserve (the scenario's start powertrain and faults are not used)")
    p.add_argument("--motor-fault", action="append", default=[], metavar="MOTOR=MAGNITUDE",
                   help="with --vehicle: a motor power loss by the description's motor name (repeatable)")
    p.set_defaults(func=cmd_plan)

    e = subparsers.add_parser("experiment", description="Experiments of the planning package.")
    e.add_argument("which", choices=("table3", "scenarios"),
                   help="table3 = print the table; scenarios = write fixtures/scenarios/table3_{7..10}.json")
    e.add_argument("--trials", type=int, default=30)
    e.add_argument("--particles", type=int, default=30)
    e.add_argument("--stronger-trials", type=int, default=None, help="trials of the stronger planner (default: --trials)")
    e.add_argument("--learned", type=Path, default=DEFAULT_LEARNED, help="learned parameter set JSON")
    e.add_argument("--out", type=Path, default=Path("fixtures/scenarios"), help="where `scenarios` writes")
    e.add_argument("--json", action="store_true")
    e.set_defaults(func=cmd_experiment)


def _deadline(seconds: float | None):
    if seconds is None:
        return None
    end = time.monotonic() + seconds
    return lambda: time.monotonic() >= end


def cmd_plan(args: argparse.Namespace) -> int:
    from gcs_pdm.missions import MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_WAYPOINT
    from gcs_pdm.planning.mission import MAV_CMD_DO_CHANGE_SPEED, plan_to_mission
    from gcs_pdm.planning.planners import plan_scenario
    from gcs_pdm.planning.scenario import Scenario, ScenarioError

    try:
        scenario = Scenario.from_json(args.scenario.read_text())
    except OSError as exc:
        print(f"gcs-pdm plan: error: cannot read {args.scenario}: {exc}", file=sys.stderr)
        return 2
    except (ScenarioError, ValueError) as exc:
        print(f"gcs-pdm plan: error: {args.scenario}: {exc}", file=sys.stderr)
        return 2
    # the vehicle flown: a description given with --vehicle, else the scenario's own (the paper's aircraft)
    described = None
    if args.vehicle:
        from gcs_pdm.planning.scenario import FlownVehicle
        from gcs_pdm.vehicle.description import VehicleError
        from gcs_pdm.vehicle.presets import resolve

        try:
            motor_faults = {}
            for spec in args.motor_fault:
                name, _, mag = spec.partition("=")
                motor_faults[name] = float(mag)
            described = FlownVehicle(resolve(args.vehicle), motor_faults=motor_faults)
        except (VehicleError, ValueError) as exc:
            print(f"gcs-pdm plan: error: {exc}", file=sys.stderr)
            return 2
    t0 = time.perf_counter()
    try:
        flown = described if described is not None else scenario.flown_vehicle()
        plan = plan_scenario(scenario, flown, args.planner, particles=args.particles, seed=args.seed, dt_s=args.dt,
                             optimise_airspeed=args.optimise_airspeed, should_stop=_deadline(args.deadline),
                             max_failure_probability=args.risk, risk_samples=args.samples)
    except ValueError as exc:
        print(f"gcs-pdm plan: error: {exc}", file=sys.stderr)
        return 2
    elapsed = time.perf_counter() - t0
    mission = plan_to_mission(scenario, plan, airborne=not args.on_ground)
    if args.mission is not None:
        from gcs_pdm.mavlink.mission_files import write_wpl

        write_wpl(args.mission, mission.items)
    if args.json:
        out = plan.to_dict()
        out["plan_time_s"] = elapsed
        out["reward_collected"] = scenario.reward_collected
        out["mission"] = {"current_seq": mission.current_seq, "items": [
            {"seq": i.seq, "command": i.command, "frame": i.frame, "x": i.x, "y": i.y, "z": i.z,
             "param2": i.param2} for i in mission.items]}
        print(json.dumps(out, default=float))
        return 0 if plan.feasible else 1
    names = {MAV_CMD_NAV_WAYPOINT: "WAYPOINT", MAV_CMD_NAV_TAKEOFF: "TAKEOFF", MAV_CMD_NAV_LAND: "LAND",
             MAV_CMD_DO_CHANGE_SPEED: "CHANGE_SPEED"}
    print(f"scenario {scenario.name}: {len(scenario.waypoints)} waypoints, faults "
          f"{', '.join(f'{f.motor} {f.magnitude:.0%}' for f in scenario.faults) or 'none'}")
    print(f"planner {plan.planner} ({elapsed * 1000:.0f} ms): route {' -> '.join(map(str, plan.numbers)) or '(none)'} -> land")
    print(f"  feasible: {plan.feasible} ({plan.failure})   reward {plan.reward:g} "
          f"(+{scenario.reward_collected:g} collected)   C_h {plan.health_cost:.3f}   C_p {plan.power_cost_mj:.3f} MJ")
    print(f"  flight time {plan.flight_time_s / 60:.1f} min; landing SoC "
          + " ".join(f"{s:.2f}" for s in plan.final_soc)
          + "; pack °C " + " ".join(f"{t:.1f}" for t in plan.final_pack_temp_c)
          + "; motor °C " + " ".join(f"{t:.1f}" for t in plan.final_motor_temp_c))
    risk = plan.stats.get("risk")
    if risk:
        q = risk["landing_soc_quantiles"]["soc"]
        print(f"  over {risk['samples']} draws: P(failure) {risk['p_failure']:.3f} (bound {risk['max_failure_probability']:g}), "
              f"lowest pack lands at {q[0]:.2f} (p05) / {q[1]:.2f} (median), expected reward {risk['expected_reward']:.1f} "
              f"of {risk['nominal_reward']:g}; median landing SoC above")
    print(f"  mission: {len(mission.items)} items, set current to seq {mission.current_seq}")
    for it in mission.items:
        what = names.get(it.command, str(it.command))
        extra = f"{it.param2:g} m/s" if it.command == MAV_CMD_DO_CHANGE_SPEED else \
            f"{it.lat_deg:.6f} {it.lon_deg:.6f} {it.z:g} m"
        print(f"    {it.seq:>2} {what:<13} {extra}")
    return 0 if plan.feasible else 1


def cmd_experiment(args: argparse.Namespace) -> int:
    from gcs_pdm.models.params import ParameterSet, builtin
    from gcs_pdm.sim.truth import true_parameters

    truth = true_parameters()
    if args.which == "scenarios":
        from gcs_pdm.planning.table3_scenario import TABLE3_SIZES, table3_scenario

        args.out.mkdir(parents=True, exist_ok=True)
        for n in TABLE3_SIZES:
            path = args.out / f"table3_{n}.json"
            path.write_text(table3_scenario(truth, n).to_json(indent=1) + "\n")
            print(f"wrote {path}")
        return 0
    from gcs_pdm.planning.experiment import format_table3, run_table3
    from gcs_pdm.planning.table3_scenario import table3_scenario

    prior = builtin("previous_si")
    note = ""
    if args.learned.exists():
        learned = ParameterSet.from_json(args.learned.read_text())
        learned_name = f"{learned.name} ({args.learned})"
    else:
        learned = builtin("paper_si")
        learned_name = "paper_si"
        note = (f"NOTE: {args.learned} does not exist yet; 'learned' falls back to the built-in paper_si set "
                "(the physical reading of the paper's learned values), not a fit of the simulated vehicle")
        log.warning(note)
    t0 = time.perf_counter()
    rows = run_table3(truth, prior, learned, trials=args.trials, particles=args.particles,
                      stronger_trials=args.stronger_trials)
    if args.json:
        print(json.dumps({"rows": [r.to_dict() for r in rows], "prior": prior.name, "learned": learned_name,
                          "truth": truth.name, "note": note, "seconds": time.perf_counter() - t0}, default=float))
        return 0
    print(format_table3(rows, prior_name=prior.name, learned_name=learned_name, truth_name=truth.name,
                        trials=args.trials, particles=args.particles,
                        collected=table3_scenario(truth, 7).reward_collected, note=note))
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0
