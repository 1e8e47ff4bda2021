"""Flying follows the airframe: a hovering multirotor is flying (armed, hover-level power), and its
time to cut-off is predicted from the description's multirotor power model; a landed or disarmed
vehicle gets no count-down but the reason why there is none."""
from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.estimation.flight_phase import FLYING_AIRSPEED_MPS, flight_phase
from gcs_pdm.sim.core import VehicleCore
from gcs_pdm.sim.model import MODE_MANUAL, MODE_RTL, vehicle_config
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.vehicle.presets import PRESETS
from gcs_pdm.mavlink.vehicle_mapping import frame_mapping

sys.path.insert(0, str(Path(__file__).parent))
from test_service_vehicle import _loop  # noqa: E402

HOVER_S = 300.0
TLOG_EPOCH_US = 1_700_000_000_000_000


def _phase(**kw):
    args = dict(multirotor=True, armed=True, landed_state=None, airspeed_mps=0.2, climb_mps=0.0,
                electrical_power_w=180.0, hover_power_w=136.0)
    return flight_phase(**{**args, **kw})


def test_the_flight_phase_follows_the_airframe():
    hover = _phase()
    assert hover.flying and "hover" in hover.reason
    idle = _phase(electrical_power_w=15.0)  # armed on the ground, props idling
    assert not idle.flying and idle.reason.startswith("on the ground: drawing 15 W")
    assert _phase(electrical_power_w=15.0, climb_mps=1.5).flying        # lifting off
    assert _phase(electrical_power_w=15.0, airspeed_mps=8.0).flying     # forward flight
    off = _phase(armed=False)
    assert not off.flying and off.reason == "disarmed (HEARTBEAT)"
    # the autopilot's landed state outranks the power (a hard landing still draws power for a moment)
    landed = _phase(landed_state=1)
    assert not landed.flying and landed.reason == "on ground (EXTENDED_SYS_STATE)"
    assert _phase(landed_state=2, electrical_power_w=15.0).flying
    assert _phase(landed_state=0).flying                                 # undefined: not evidence
    unknown = _phase(electrical_power_w=None)
    assert not unknown.flying and "no battery power" in unknown.reason
    # a fixed wing hovering is not a thing: below the flying airspeed it is on the ground, whatever it draws
    plane = dict(multirotor=False, hover_power_w=None)
    assert not _phase(**plane).flying and "below 5 m/s" in _phase(**plane).reason
    assert _phase(**plane, airspeed_mps=FLYING_AIRSPEED_MPS + 1).flying
    assert _phase(**plane, airspeed_mps=None).reason == "no airspeed telemetry yet"


def _hover_tlog(path: Path) -> dict:
    """The sim's quad-4s: waits disarmed, takes off, hovers HOVER_S in MANUAL (the sim's
    multirotor holds position), flies home and lands (disarmed). Every packet into a tlog."""
    desc = PRESETS["quad-4s"]
    mission = tuple(mission_from_enu([(200, 0, 30)], takeoff_alt_m=30))
    core = VehicleCore(vehicle_config(desc, mission=mission, start_delay_s=35.0))
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()
    times: dict = {}
    while core.time_s < 3600.0:
        msgs = core.tick()
        s = core.last_state
        if "hover" not in times and not s.on_ground and s.alt_m >= 25.0:
            core.model.set_mode(MODE_MANUAL)
            times["hover"] = s.time_s
        if "home" not in times and "hover" in times and s.time_s - times["hover"] >= HOVER_S:
            core.model.set_mode(MODE_RTL)
            times["home"] = s.time_s
        stamp = struct.pack(">Q", TLOG_EPOCH_US + int(round(core.time_s * 1e6)))
        for m in msgs:
            out += stamp + m.pack(mav)
        if "home" in times and "down" not in times and core.model.finished:
            times["down"] = s.time_s
        if "down" in times and core.time_s > times["down"] + 40.0:
            break
    assert {"hover", "home", "down"} <= set(times) and not core.last_state.armed and core.last_state.landed
    path.write_bytes(bytes(out))
    return times


class _Inline:
    """The intake's prediction worker, run inline so every prediction is seen in order."""

    def submit(self, fn):
        fn()

    def shutdown(self, **kw):
        pass


def test_the_sims_hovering_quad_gets_a_falling_time_to_cutoff_and_a_landed_one_the_reason(tmp_path):
    desc = PRESETS["quad-4s"]
    times = _hover_tlog(tmp_path / "hover.tlog")
    svc, loop = _loop(tmp_path, "quad-4s")
    try:
        loop.telemetry._predictor = _Inline()
        seen = []

        def consume(frame):
            loop.process(frame)
            p = svc.state.get("prediction")
            if p and (not seen or seen[-1]["time_s"] != p["time_s"]):
                seen.append({**p, "ttc": svc.state.get("packs")["battery"]["time_to_cutoff_s"]})

        replay_tlog(tmp_path / "hover.tlog", mapper=FrameMapper(frame_mapping(desc)), frame_consumer=consume)
        # waiting disarmed on the ground: no count-down, and why
        before = [p for p in seen if p["time_s"] < times["hover"] - 15.0]
        assert before and all(p["ttc"] is None and p["stale"] and not p["flying"] for p in before)
        assert before[-1]["reason"] == "not flying: disarmed (HEARTBEAT)"
        # hovering (zero airspeed): a finite time to cut-off from the hover power, falling
        hover = [p for p in seen if times["hover"] + 10.0 <= p["time_s"] <= times["home"]]
        assert len(hover) >= 25
        for p in hover:
            assert p["flying"] and not p["stale"] and p["reason"] is None and "hover" in p["flight"]
            assert p["ttc"] is not None and math.isfinite(p["ttc"]) and p["ttc"] > 0
            assert p["shaft_power_w"] == pytest.approx(136.0, rel=0.05)  # momentum theory's hover at 30 m
        t = np.array([p["time_s"] for p in hover])
        ttc = np.array([p["ttc"] for p in hover])
        slope = np.polyfit(t, ttc, 1)[0]
        assert -1.5 < slope < -0.6                                 # about a second per second of hover
        assert ttc[-1] < ttc[0] - 0.5 * (t[-1] - t[0])
        # landed and disarmed after the flight home: the count-down is gone, the reason is there
        after = [p for p in seen if p["time_s"] > times["down"] + 5.0]
        assert after and all(p["ttc"] is None and not p["flying"] for p in after)
        assert after[-1]["reason"] == "not flying: disarmed (HEARTBEAT)"
        assert after[-1].get("packs") is None and after[-1].get("flight") is None  # the flight's numbers cleared
    finally:
        svc.close()


class _Messages:
    def __init__(self, msgs):
        self.msgs = list(msgs)

    def get(self, timeout=None):
        return self.msgs.pop(0) if self.msgs else None

    def close(self):
        pass


def test_extended_sys_state_says_landed_though_armed_and_drawing_power(tmp_path):
    from gcs_pdm.frames import AirdataFrame, MotorFrame, PackFrame, StatusFrame

    svc, loop = _loop(tmp_path, "quad-4s")
    try:
        intake = loop.telemetry
        intake._predictor = _Inline()
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)

        def sys_state(landed):
            m = mav.extended_sys_state_encode(0, landed)
            return mav.decode(bytearray(m.pack(mav)))

        def second(t):
            loop.process(StatusFrame(t, True, "AUTO", 4))
            loop.process(AirdataFrame(t, 0.0, 0.0, 0.0, 50.0, 0.0))
            loop.process(PackFrame(t, "battery", 15.6, 11.5, 25.0))
            for m in PRESETS["quad-4s"].motor_names:
                loop.process(MotorFrame(t, m, 2.8, 6000.0, 30.0))

        for t in range(0, 12):
            second(float(t))
        p = svc.state.get("prediction")
        assert p["flying"] and svc.state.get("packs")["battery"]["time_to_cutoff_s"] > 0  # hover power
        intake._messages = _Messages([sys_state(1)])                # the autopilot: on ground
        intake._pass_messages()
        for t in range(12, 23):
            second(float(t))
        p = svc.state.get("prediction")
        assert not p["flying"] and p["reason"] == "not flying: on ground (EXTENDED_SYS_STATE)"
        assert svc.state.get("packs")["battery"]["time_to_cutoff_s"] is None
        # an old verdict no longer counts once the vehicle stops sending it: power decides again
        for t in range(23, 45):
            second(float(t))
        assert svc.state.get("prediction")["flying"]
    finally:
        svc.close()
