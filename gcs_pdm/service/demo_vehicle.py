"""``gcs-pdm demo --vehicle P``: the demo on a vehicle description other than the paper's aircraft.

The simulated vehicle (``gcs_pdm.sim`` flying the description, ``sim.model.vehicle_config``) takes
off on a square survey of seven waypoints with its packs part-charged (as after an earlier sortie);
half way from waypoint 2 to 3 one motor loses part of its power. The service, told the description,
diagnoses the fault where the telemetry shows it (a multirotor: the imbalance between its ESCs),
replans with the weakened motor (the current mission would now break the landing reserve), uploads
the new mission, confirms it by download; the vehicle lands. The terminal shows it as it happens.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from gcs_pdm.service.demo import (DecisionHold, TerminalPrinter, close_demo, demo_config, demo_telemetry,
                                  fly_until_on_ground, start_status_page)
from gcs_pdm.service.runtime import Service

#: the survey about home (east m, north m, altitude m), scaled to the vehicle's cruise speed
SURVEY = ((1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1))
#: charge at take-off: enough for the survey healthy, not with the fault (the story needs a choice).
#: The risk-bounded verdict (the landing SoC's p05 over the draws keeps the reserve) asks more than
#: the nominal one did. Since its draws count a self-calibrated pack's capacity once (not again on
#: top of its SoC σ), on quad-4s: from 36 % no route keeps it, from 46 % the survey still does
#: (docs/notes/2026-11-27-risk-presets.md)
INITIAL_SOC = 0.40
FAULT_MAGNITUDE = 0.6


@dataclass
class VehicleDemoResult:
    vehicle: str
    landed: bool
    failed: bool
    failure: str
    fault_injected_s: float | None
    fault_detected_s: float | None
    fault_source: str | None
    plans: int
    uploads: int
    reached: list[int]
    sim_time_s: float
    wall_s: float
    readiness: dict


def survey_mission(desc):
    from gcs_pdm.sim.routes import mission_from_enu

    side = 30.0 * desc.cruise_speed_mps  # 30 s legs
    alt = 40.0 if desc.airframe.type == "multirotor" else 80.0
    return mission_from_enu([(e * side, n * side, alt) for e, n in SURVEY], takeoff_alt_m=alt)


def run_vehicle_demo(vehicle: str, *, speedup: float = 8.0, http_port: int = 8000, data_dir: str | None = None,
                     seed: int = 0, timeout_s: float = 170.0, out=print, policy: str = "auto",
                     hold_while_deciding: bool = False) -> VehicleDemoResult:
    """``hold_while_deciding``: the vehicle's clock stops while the service decides (the tests'
    mode, ``demo.DecisionHold``); the command flies on at its speed-up like a real aircraft."""
    from gcs_pdm.service.adapters import start_sim_vehicle
    from gcs_pdm.service.server import start_mavlink, stop_mavlink
    from gcs_pdm.sim.faults import parse_fault
    from gcs_pdm.sim.model import vehicle_config
    from gcs_pdm.vehicle.presets import resolve

    wall0 = time.monotonic()
    desc = resolve(vehicle)
    mission = survey_mission(desc)
    motor = desc.motors[min(1, len(desc.motors) - 1)].name
    fault = parse_fault(f"motor:{motor}:{FAULT_MAGNITUDE}@leg:3-4", desc.motor_names)
    cfg_sim = vehicle_config(desc, mission=tuple(mission), initial_soc=INITIAL_SOC, faults=(fault,), seed=seed)
    config, tmp, port, _token = demo_config(data_dir, policy=policy, http_port=http_port,
                                            hold_while_deciding=hold_while_deciding, vehicle=vehicle,
                                            planner_deadline_s=5.0)
    service = Service(config)
    http = start_status_page(service, out)
    out(f"  vehicle: simulated {desc.name} ({desc.description}), x{speedup:g} real time, MAVLink udp 127.0.0.1:{port}")
    out(f"  service: policy {policy}, vehicle description {desc.name!r}")
    out(f"  mission: a survey of {len(SURVEY)} waypoints from {INITIAL_SOC:.0%} charge; motor {motor} will lose "
        f"{FAULT_MAGNITUDE:.0%} of its power half way from waypoint 2 to 3")
    printer = TerminalPrinter(service, out).start()
    start_mavlink(service)
    out(f"  readiness: {service.state.get('readiness')}")
    hold = DecisionHold(service) if hold_while_deciding else None
    sim = start_sim_vehicle(cfg_sim, f"udpout:127.0.0.1:{port}", speedup, demo_telemetry(), hold=hold)
    if hold is not None:
        hold.vehicle = sim
    try:
        fly_until_on_ground(sim, wall0, timeout_s, out, every_s=60.0)
    finally:
        readiness = service.state.get("readiness")
        sim.stop()
        stop_mavlink(service)
        printer.stop()
    s = sim.state
    faults = [f for f in service.store.faults() if f["kind"] == "motor_power_loss"]
    result = VehicleDemoResult(
        vehicle=desc.name, landed=bool(s.landed and not s.failed), failed=bool(s.failed), failure=s.failure,
        fault_injected_s=sim.fault_log[0]["time_s"] if sim.fault_log else None,
        fault_detected_s=faults[0]["time_s"] if faults else None, fault_source=faults[0]["source"] if faults else None,
        plans=len(service.store.plans()),
        uploads=len([u for u in service.store.uploads() if u["status"] == "confirmed"]),
        # waypoint numbers as the service matched them (the mission's seqs change with each upload)
        reached=[e.data["waypoint"] for e in service.events.since(0)
                 if e.kind == "mission" and e.data.get("waypoint") is not None], sim_time_s=float(s.time_s),
        wall_s=time.monotonic() - wall0, readiness=readiness or {})
    close_demo(http, service, tmp)
    return result


def print_vehicle_summary(r: VehicleDemoResult, out=print) -> None:
    out("")
    out(f"=== summary ({r.vehicle}) ===")
    if r.fault_injected_s is not None:
        out(f"fault injected at t={r.fault_injected_s:.1f} s, "
            + (f"diagnosed at t={r.fault_detected_s:.1f} s ({r.fault_source})" if r.fault_detected_s is not None
               else "not diagnosed"))
    out(f"motor diagnosis: {r.readiness.get('motor_diagnosis', 'unknown')}")
    out(f"waypoints reached: {r.reached}")
    out(f"{r.plans} plan(s), {r.uploads} confirmed upload(s); "
        + ("landed safely" if r.landed else (f"FAILED: {r.failure}" if r.failed else "still flying (timeout)"))
        + f" at t={r.sim_time_s:.0f} s; {r.wall_s:.0f} s wall time")
