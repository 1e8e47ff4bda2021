"""Every capability for every preset (issue 32): the simulated vehicle of each preset over loopback
UDP, the service told that preset, a motor fault injected. The plan the service makes of it carries
a numeric probability of failure and the landing SoC's p05/p50/p95 (the risk-bounded planner's, over
its draws, and the Monte Carlo route risk's); the current mission's outlook has them too. A
multirotor hovering (held in MANUAL) gets a time to cut-off.

Kept short and load-proof: the test ends at the plan, at a high speed-up; the vehicle's clock
waits while the service decides (``demo.DecisionHold``), so when the plan is made does not depend
on the machine. A fault the telemetry cannot show (the plane's single motor) is declared by the
operator, as in tests/test_end_to_end_vehicles.py.
"""
from __future__ import annotations

import math
import time

import pytest

from gcs_pdm.service.adapters import start_sim_vehicle
from gcs_pdm.service.config import load_config
from gcs_pdm.service.demo import DecisionHold, demo_telemetry, free_udp_port
from gcs_pdm.service.demo_vehicle import SURVEY
from gcs_pdm.service.runtime import Service
from gcs_pdm.service.server import start_mavlink, stop_mavlink
from gcs_pdm.sim.faults import parse_fault
from gcs_pdm.sim.model import MODE_AUTO, MODE_MANUAL, vehicle_config
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.vehicle.presets import PRESETS

PRESET_NAMES = ("edge540", "plane-3s", "quad-4s", "quad-6s", "hex-6s")
#: charge at take-off and the survey's leg: with the fault the survey breaks the landing reserve while a
#: shorter route still keeps it on every preset, so the service proposes (measured: from 0.45 the
#: multirotors had no route that keeps it, from 0.6 two of them kept the mission). hex-6s keeps it
#: from 0.5 since its calibrated packs' capacity counts once in the risk draws
#: (docs/notes/2026-11-27-risk-presets.md)
SOC = {"hex-6s": 0.45}
DEFAULT_SOC = 0.5
LEG_S = 90.0
SPEEDUP = 30.0
#: wall seconds any one wait may take on a loaded machine (the clock is held while the service works)
WAIT_S = 120.0
#: message seconds a multirotor hovers: long enough for two of the service's predictions (every 10 s)
HOVER_S = 25.0


def _wait(what: str, check, timeout_s: float = WAIT_S):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        got = check()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"not within {timeout_s:g} s: {what}")


def _numeric_quantiles(q) -> bool:
    return (len(q) == 3 and all(isinstance(v, float) and math.isfinite(v) for v in q)
            and 0.0 <= q[0] <= q[1] <= q[2] <= 1.0)


def _survey(desc):
    side = LEG_S * desc.cruise_speed_mps
    alt = 40.0 if desc.airframe.type == "multirotor" else 80.0
    return mission_from_enu([(e * side, n * side, alt) for e, n in SURVEY], takeoff_alt_m=alt)


class _Flight:
    """The service (policy advise, ``preset`` as its vehicle) and the simulated vehicle of ``preset``
    on a survey of 90-second legs from half-charged packs, its second motor (or its only one) losing
    60 % of its power on the way from waypoint 1 to 2."""

    def __init__(self, tmp_path, preset: str):
        desc = self.desc = PRESETS[preset]
        motor = self.motor = desc.motors[min(1, len(desc.motors) - 1)].name
        fault = parse_fault(f"motor:{motor}:0.6@leg:1-2", desc.motor_names)
        port = free_udp_port()
        self.service = Service(load_config(
            env={}, data_dir=str(tmp_path), api_token="risk-presets-token-0123456789", policy="advise",
            mavlink_url=f"udpin:127.0.0.1:{port}", record_tlog=False, vehicle=preset, link_lost_after_s=600.0,
            planner_deadline_s=3.0, particles=10, risk_samples=100))
        start_mavlink(self.service)
        self.hold = DecisionHold(self.service)
        cfg = vehicle_config(desc, mission=tuple(_survey(desc)), initial_soc=SOC.get(preset, DEFAULT_SOC), faults=(fault,), seed=0)
        self.vehicle = start_sim_vehicle(cfg, f"udpout:127.0.0.1:{port}", SPEEDUP, demo_telemetry(), hold=self.hold)
        self.hold.vehicle = self.vehicle

    def close(self) -> None:
        self.vehicle.stop()
        stop_mavlink(self.service)
        self.service.close()


def _hover_time_to_cutoff(flight: _Flight) -> dict:
    """Hold the airborne multirotor in MANUAL (the sim holds its position) until the service predicts
    from the hover, then back to AUTO; the prediction made in the hover."""
    svc, vehicle = flight.service, flight.vehicle
    _wait("the multirotor at altitude", lambda: vehicle.state.alt_m > 20.0 and not vehicle.state.on_ground)
    vehicle.call(lambda core: core.model.set_mode(MODE_MANUAL))
    t0 = vehicle.state.time_s

    def hovering_prediction():
        p = svc.state.get("prediction") or {}
        return p if (p.get("flying") and p.get("time_s", -1.0) > t0 + 5.0 and "hover" in (p.get("flight") or "")
                     and vehicle.state.time_s - t0 >= HOVER_S) else None

    pred = _wait("a prediction while hovering", hovering_prediction)
    packs = {n: svc.state.get("packs")[n]["time_to_cutoff_s"] for n in flight.desc.pack_names}
    vehicle.call(lambda core: core.model.set_mode(MODE_AUTO))
    return {"prediction": pred, "packs": packs, "airspeed": vehicle.state.airspeed_mps}


@pytest.mark.timeout(600)
@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_a_motor_fault_gets_a_plan_with_its_probability_of_failure_and_landing_soc(tmp_path, preset):
    flight = _Flight(tmp_path, preset)
    svc, vehicle = flight.service, flight.vehicle
    try:
        hover = _hover_time_to_cutoff(flight) if flight.desc.airframe.type == "multirotor" else None
        _wait("the fault injected", lambda: vehicle.fault_log)
        if preset == "plane-3s":  # its ESC cannot show its own loss: the operator declares it
            svc.declare_fault("motor_power_loss", flight.motor, 0.6, "seen on the GCS", replan=True)
        faults = _wait("the motor fault known to the service",
                       lambda: [f for f in svc.store.faults() if f["kind"] == "motor_power_loss"])
        assert faults[0]["target"] == flight.motor

        def plan_after_fault():
            return [p for p in svc.store.plans() if p["time_s"] >= faults[0]["time_s"]
                    and p["status"] in ("proposed", "kept", "superseded")]

        plan = _wait("a plan made with the fault", plan_after_fault)[-1]
        assert plan["status"] in ("proposed", "superseded"), plan["status"]  # superseded: by a newer proposal
        chosen = plan["chosen"]
        # the risk-bounded planner's verdict over its draws of the description's packs and motors
        risk = chosen["risk"]
        assert isinstance(risk["p_failure"], float) and 0.0 <= risk["p_failure"] <= 1.0
        assert risk["samples"] == 100 and _numeric_quantiles(risk["landing_soc_quantiles"]["soc"])
        # the Monte Carlo route risk from the estimator (what the operator weighs the plan with)
        assert isinstance(chosen["failure_probability"], float) and 0.0 <= chosen["failure_probability"] <= 1.0
        assert chosen["landing_samples"] > 0
        assert _numeric_quantiles([chosen["landing_soc"][k] for k in ("p05", "p50", "p95")])
        # and the current mission's outlook: numbers, not "unknown"
        outlook = _wait("the outlook", lambda: (o := svc.state.get("outlook")) and "p_failure" in o and o)
        assert isinstance(outlook["p_failure"], float)
        assert _numeric_quantiles([outlook[f"landing_soc_p{k}"] for k in ("05", "50", "95")])
        if hover is not None:
            assert hover["airspeed"] < 1.0
            ttc = list(hover["packs"].values())
            assert all(v is not None and 0.0 < v < math.inf for v in ttc), hover
            assert hover["prediction"]["shaft_power_w"] > 0.0
    finally:
        flight.close()
