"""Wind, issue 31's three "Done when" bullets as figures (tests/test_wind.py asserts on the same functions).

1. **/status**: ``gcs-pdm sim``'s vehicle (the Table III mission, no fault) flies in ``--wind SPEED@FROM``
   with gusts over loopback UDP to a ``Service``; every reading of ``/status``'s wind from vehicle time
   ``--settle`` s on, for ``--window`` s, is compared with the simulator's set wind: the speed error and
   the direction error, worst and median, the share of readings within 1 m/s and 20°, and the speed error
   against the wind in force at that moment (mean plus gust). Twice: the autopilot's ``WIND`` message,
   and a vehicle that sends none (the service's wind triangle: ground velocity minus the airspeed vector).
2. **Headwind**: one long leg east, beyond what the packs can fly, in calm air and into an 8 m/s headwind:
   the planner simulator's flight time to cut-off and the Monte Carlo prediction's median time to failure.
3. **The planner's choice**: table3_7's calm optimum (exact search) flown in ``--wind``: does it still get
   home with its reserve, and what does the planner choose in that wind.

    python benchmarks/bench_wind.py [--wind 8@270] [--gust SIGMA] [--settle 90] [--window 60] [--speedup 8]

Prints one line per measurement, then the figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs_pdm.models.wind import wind_from_speed_direction  # noqa: E402
from gcs_pdm.planning.planners import plan_scenario  # noqa: E402
from gcs_pdm.planning.scenario import Scenario, Waypoint  # noqa: E402
from gcs_pdm.planning.simulator import VehicleSimulator  # noqa: E402
from gcs_pdm.planning.table3_scenario import table3_scenario  # noqa: E402
from gcs_pdm.sim.truth import true_parameters  # noqa: E402


def angle_diff(a: float, b: float) -> float:
    """The smaller angle between two compass directions, degrees."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def status_wind(data_dir: str, send_wind: bool, speed_mps: float = 8.0, from_deg: float = 270.0,
                settle_s: float = 90.0, window_s: float = 0.0, speedup: float = 8.0,
                deadline_s: float = 150.0, gust_mps: float | None = None) -> dict:
    """Fly the simulated vehicle in a gusty wind and read the service's ``/status`` wind from vehicle time
    ``settle_s`` to ``settle_s + window_s`` (at least one reading). ``send_wind`` False: the vehicle sends
    no ``WIND`` (streams not requested), so the service must use the wind triangle. ``deadline_s``: wall
    seconds before giving up (a loaded 2-CPU machine). ``gust_mps``: the gusts' 1-sigma per component;
    None is ``sim --wind``'s default, 15 % of the mean speed."""
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.demo import sim_config, table3_mission
    from gcs_pdm.service.runtime import Service
    from gcs_pdm.service.server import start_mavlink, stop_mavlink
    from gcs_pdm.sim.telemetry import DEFAULT_RATES, TelemetryConfig
    from gcs_pdm.sim.vehicle import SimulatedVehicle

    source = "autopilot" if send_wind else "triangle"
    scenario, mission = table3_mission()
    port = _free_udp_port()
    svc = Service(load_config(env={}, data_dir=data_dir, api_token="wind-token-0123456789abcdef",
                              policy="advise", mavlink_url=f"udpin:127.0.0.1:{port}", record_tlog=False,
                              vehicle="edge540", request_streams=send_wind))
    svc.load_objectives_scenario(scenario)
    start_mavlink(svc)
    config = dataclasses.replace(sim_config(scenario, mission), faults=(),
                                 wind_en_mps=wind_from_speed_direction(speed_mps, from_deg),
                                 wind_gust_mps=0.15 * speed_mps if gust_mps is None else gust_mps)
    rates = dict(DEFAULT_RATES, WIND=1.0 if send_wind else 0.0)
    vehicle = SimulatedVehicle(config, f"udpout:127.0.0.1:{port}", speedup=speedup,
                               telemetry=TelemetryConfig(rates_hz=rates)).start()
    readings: list[dict] = []
    try:
        deadline = time.monotonic() + deadline_s
        while time.monotonic() < deadline:
            truth = vehicle.state
            t = truth.time_s
            if t > settle_s + window_s and readings:
                break
            w = svc.state.get("wind")
            if t > settle_s and "speed_mps" in w and w["source"] == source:
                readings.append({"vehicle_time_s": t, "speed_mps": w["speed_mps"], "from_deg": w["from_deg"],
                                 "in_force_en_mps": (truth.wind_east_mps, truth.wind_north_mps)})
            time.sleep(0.2)
        last_seen = svc.state.get("wind")
    finally:
        vehicle.stop()
        stop_mavlink(svc)
        svc.close()
    speed_err = [abs(r["speed_mps"] - speed_mps) for r in readings]
    dir_err = [angle_diff(r["from_deg"], from_deg) for r in readings]
    within = [e <= 1.0 and d <= 20.0 for e, d in zip(speed_err, dir_err)]
    # against the wind in force at that moment (the mean plus the gust): what a 1-Hz reading could follow
    gusty_err = [abs(r["speed_mps"] - float(np.hypot(*r["in_force_en_mps"]))) for r in readings]
    return {"source": source, "set": {"speed_mps": speed_mps, "from_deg": from_deg, "gust_mps": config.wind_gust_mps},
            "readings": len(readings),
            "first": readings[0] if readings else None, "last_seen": last_seen,
            "speed_error_max_mps": max(speed_err, default=None),
            "speed_error_median_mps": float(np.median(speed_err)) if readings else None,
            "direction_error_max_deg": max(dir_err, default=None),
            "direction_error_median_deg": float(np.median(dir_err)) if readings else None,
            "share_within_1mps_20deg": float(np.mean(within)) if readings else None,
            "speed_error_vs_in_force_median_mps": float(np.median(gusty_err)) if readings else None,
            "speed_error_vs_in_force_max_mps": max(gusty_err, default=None),
            "met_first": bool(readings) and speed_err[0] <= 1.0 and dir_err[0] <= 20.0,
            "met_all": bool(readings) and max(speed_err) <= 1.0 and max(dir_err) <= 20.0}


def headwind_cutoff(scenario: Scenario, speed_mps: float = 8.0) -> dict:
    """One long leg east (60 km, beyond the packs) in calm air and into a headwind from the east: the
    planner simulator's flight time (both cut off on the way out) and the prediction's median time to
    failure over 64 draws of state and parameters, the second motor at 70 % loss."""
    from gcs_pdm.estimation.prediction import load_for_route, predict

    far = dataclasses.replace(scenario, waypoints=(Waypoint(number=1, east_m=scenario.start.east_m + 60_000.0,
                                                            north_m=scenario.start.north_m, alt_m=100.0,
                                                            reward=50.0),))
    calm_sim = VehicleSimulator.for_scenario(far, optimise_airspeed=True)
    head_sim = VehicleSimulator.for_scenario(far.with_wind(*wind_from_speed_direction(speed_mps, 90.0)), optimise_airspeed=True)
    out = {}
    x = calm_sim.initial.pack_state
    for name, sim in (("calm", calm_sim), ("headwind", head_sim)):
        ev = sim.evaluate([[0]])
        pred = predict(far.parameter_set(), x, np.zeros((4, 4, 4)), np.asarray(calm_sim.initial.motor_temp_c),
                       np.zeros(2), load_for_route(sim, [0]), rng=np.random.default_rng(3), n_samples=64,
                       fault=np.array([0.0, 0.7]), trajectories=False)
        out[name] = {"simulator_flight_time_s": float(ev.flight_time_s[0]), "fail_leg": int(ev.fail_leg[0]),
                     "airspeed_out_mps": float(sim.legs.airspeed[sim.start_node, 0]),
                     "prediction_time_to_failure_p50_s": float(pred.time_to_failure_s[1])}
    out["met"] = (out["headwind"]["simulator_flight_time_s"] < out["calm"]["simulator_flight_time_s"]
                  and out["headwind"]["prediction_time_to_failure_p50_s"]
                  < out["calm"]["prediction_time_to_failure_p50_s"])
    return out


def choice_in_wind(scenario: Scenario, speed_mps: float = 8.0, from_deg: float = 270.0) -> dict:
    """The calm optimum (exact search) flown in the wind, and the planner's choice in that wind."""
    calm_plan = plan_scenario(scenario, scenario.flown_vehicle(), "exact")
    windy = scenario.with_wind(*wind_from_speed_direction(speed_mps, from_deg))
    calm_route_in_wind = VehicleSimulator.for_scenario(windy).evaluate([calm_plan.route])
    windy_plan = plan_scenario(windy, windy.flown_vehicle(), "exact")
    return {"calm_route": list(calm_plan.numbers), "calm_route_feasible_in_calm": bool(calm_plan.feasible),
            "calm_route_feasible_in_wind": bool(calm_route_in_wind.feasible[0]),
            "wind_route": list(windy_plan.numbers), "wind_route_feasible": bool(windy_plan.feasible),
            "met": bool(calm_plan.feasible and not calm_route_in_wind.feasible[0] and windy_plan.feasible
                        and windy_plan.route != calm_plan.route)}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--wind", default="8@270", help="SPEED@FROM_DEG, as sim --wind")
    ap.add_argument("--settle", type=float, default=90.0, help="vehicle seconds before the first reading")
    ap.add_argument("--window", type=float, default=60.0, help="vehicle seconds of readings after it")
    ap.add_argument("--speedup", type=float, default=8.0)
    ap.add_argument("--gust", type=float, default=None, help="gusts' 1-sigma m/s (default as sim: 15 %% of the speed)")
    args = ap.parse_args()
    speed_mps, from_deg = (float(v) for v in args.wind.split("@"))
    sc = table3_scenario(true_parameters(), 7)
    result = {"wind": args.wind, "load_average_1min": os.getloadavg()[0]}
    status = []
    for send_wind in (True, False):
        with tempfile.TemporaryDirectory(prefix="bench-wind-") as d:
            s = status_wind(d, send_wind, speed_mps, from_deg, args.settle, args.window, args.speedup,
                            deadline_s=150.0 + 2 * args.window, gust_mps=args.gust)
        status.append(s)
        print(f"/status wind from the {s['source']}: {s['readings']} readings; speed error max "
              f"{s['speed_error_max_mps']} m/s (median {s['speed_error_median_mps']}), direction error max "
              f"{s['direction_error_max_deg']} deg (median {s['direction_error_median_deg']}); within 1 m/s and 20 deg: "
              f"first {s['met_first']}, all {s['met_all']}, share {s['share_within_1mps_20deg']:.2f}; speed error "
              f"against the gusty wind in force: median {s['speed_error_vs_in_force_median_mps']:.2f}, max "
              f"{s['speed_error_vs_in_force_max_mps']:.2f} m/s", flush=True)
    result["status"] = status
    result["headwind"] = headwind_cutoff(sc)
    h = result["headwind"]
    print(f"headwind 8 m/s: flight time to cut-off {h['headwind']['simulator_flight_time_s']:.0f} s vs calm "
          f"{h['calm']['simulator_flight_time_s']:.0f} s; predicted median time to failure "
          f"{h['headwind']['prediction_time_to_failure_p50_s']:.0f} s vs {h['calm']['prediction_time_to_failure_p50_s']:.0f}"
          f" s -> shorter {h['met']}", flush=True)
    result["choice"] = choice_in_wind(sc, speed_mps, from_deg)
    c = result["choice"]
    print(f"table3_7: calm optimum {c['calm_route']} feasible in {args.wind}: {c['calm_route_feasible_in_wind']}; "
          f"the planner's choice in it {c['wind_route']} -> changed {c['met']}", flush=True)
    result["load_average_1min_end"] = os.getloadavg()[0]
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
