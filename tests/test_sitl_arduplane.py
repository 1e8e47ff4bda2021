"""The service alone beside ArduPlane SITL (``../shared/sitl``), no vehicle description given, the
autopilot streaming nothing on its serial port until asked (its serial0 stream rates at 0).

ArduPlane's simulated battery is not a battery (voltage = SIM_BATT_VOLTAGE - 0.7 x throttle, it
never drains; ../shared/sitl/README.md): there is no truth to hold the SoC to, only the autopilot's
own charge count. So, firm: the service asks for the streams and they come, a 3-cell fixed wing is
derived from them, the plane, sent a mission through the service's link and put in AUTO, flies it,
and the service follows (airspeed, flight phase, a SoC for its pack). Measured and reported: the
SoC against the autopilot's count (``battery_remaining``) over the flight.
"""
from __future__ import annotations

import json
import time

import pytest

import sitl_support as S

pytestmark = [pytest.mark.skipif(not S.available("arduplane"), reason=f"ArduPlane SITL not found in {S.SITL}"),
              pytest.mark.slow]

SPEEDUP = 4
FLIGHT_S = 90.0


def fly_plane(tmp_path, flight_s: float = FLIGHT_S, speedup: float = SPEEDUP) -> dict:
    from gcs_pdm.mavlink.mission_client import MissionClient
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service
    from gcs_pdm.service.server import start_mavlink, stop_mavlink

    port = S.free_udp_port()
    svc = Service(load_config(env={}, data_dir=str(tmp_path / "service"), api_token="sitl-plane-token-0123456789",
                              mavlink_url=f"udpin:127.0.0.1:{port}", record_tlog=True))
    start_mavlink(svc)
    params = {**S.SILENT_STREAMS, "ARMING_CHECK": 0, "THR_FAILSAFE": 0, "FS_GCS_ENABL": 0, "SIM_BATT_VOLTAGE": 12.6}
    sitl = S.start_sitl("arduplane", tmp_path / "sitl", port, model="plane",
                        defaults=[str(S.SITL / "plane.parm")], params=params, speedup=speedup)
    commander = truth = None
    out: dict = {"speedup": speedup}
    started = time.monotonic()
    try:
        loop = svc.loop
        streams = lambda: svc.state.get("streams") or {}  # noqa: E731
        S.wait_for(lambda: streams().get("vehicle_identified"), "ArduPlane's heartbeat", 60, sitl)
        S.wait_for(lambda: streams()["streams"]["battery"]["state"] == "receiving", "BATTERY_STATUS, asked for", 60, sitl)
        out["streams_at_start"] = {k: {f: v[f] for f in ("state", "asks", "rate_hz_asked")}
                                   for k, v in streams()["streams"].items()}
        S.wait_for(lambda: svc.vehicle is not None, "a provisional description derived from telemetry", 120, sitl)
        out["vehicle"] = {"name": svc.vehicle.name, "cells": [p.cells_series for p in svc.vehicle.packs],
                          "capacity_mah": [p.capacity_mah for p in svc.vehicle.packs],
                          "airframe": svc.vehicle.airframe.type, "motors": [m.esc_index for m in svc.vehicle.motors]}
        S.wait_for(lambda: loop.estimator.ready(), "the estimator ready", 60, sitl)
        S.wait_for(lambda: loop.home is not None, "home (the service's read of the mission)", 180, sitl)
        MissionClient(loop.link).upload(S.square_mission(loop.home, side_m=600.0, alt_m=80.0, laps=3))
        truth = S.BatteryTruth(loop.link, loop.telemetry)
        commander = S.Commander(loop.link)
        commander.until_accepted(S.MAV_CMD_COMPONENT_ARM_DISARM, 1, what="arming", timeout=180, sitl=sitl)
        commander.until_accepted(S.MAV_CMD_DO_SET_MODE, 1, S.PLANE_AUTO, what="AUTO", timeout=60, sitl=sitl)
        start_s = loop.telemetry.time_s
        pack_name = svc.vehicle.packs[0].name
        trace = []
        while loop.telemetry.time_s - start_s < flight_s:
            S.wait_for(lambda: sitl.proc.poll() is None, "SITL running", 1, sitl)
            time.sleep(0.25)
            truth.poll()
            p = (svc.state.get("packs") or {}).get(pack_name) or {}
            if not truth.samples:
                continue
            trace.append({"t": round(loop.telemetry.time_s - start_s, 2), "soc": p.get("soc"),
                          "autopilot_remaining": truth.samples[-1][2] / 100.0,
                          "airspeed": (svc.state.get("airdata") or {}).get("airspeed"),
                          "alt_m": (svc.state.get("position") or {}).get("relative_alt_m")})
        socs = [s for s in trace if s["soc"] is not None]
        diffs = [abs(s["soc"] - s["autopilot_remaining"]) for s in socs]
        out.update({"trace": trace[:: max(1, len(trace) // 12)] + [trace[-1]], "samples": len(trace),
                    "soc_null_samples": len(trace) - len(socs),
                    "soc_vs_autopilot_max": round(max(diffs), 4) if diffs else None,
                    "max_airspeed": max((s["airspeed"] or 0.0) for s in trace),
                    "max_alt_m": max((s["alt_m"] or 0.0) for s in trace), "drawn_ah": truth.drawn_ah(),
                    "readiness": svc.state.get("readiness"),
                    "prediction": {k: (svc.state.get("prediction") or {}).get(k) for k in ("flying", "reason", "flight")},
                    "streams_at_end": {k: v["state"] for k, v in streams()["streams"].items()},
                    "wall_s": round(time.monotonic() - started, 1)})
        return out
    finally:
        for part in (commander, truth):
            if part is not None:
                part.close()
        sitl.stop()
        stop_mavlink(svc)
        svc.close()


def test_arduplane_alone_beside_the_service(tmp_path):
    figures = fly_plane(tmp_path)
    print("SITL_FIGURES " + json.dumps(figures))
    assert figures["streams_at_start"]["battery"]["asks"] >= 1
    assert figures["streams_at_end"]["battery"] == "receiving" and figures["streams_at_end"]["airspeed"] == "receiving"
    assert figures["vehicle"]["cells"] == [3] and figures["vehicle"]["airframe"] == "fixed_wing"
    assert figures["max_airspeed"] > 15.0 and figures["max_alt_m"] > 30.0  # it flew its mission
    assert figures["prediction"]["flying"] is True
    assert figures["drawn_ah"] > 0.05
    # the pack's SoC after the first minute: issue 29 wants it never withheld (items 1-3, the estimator)
    late = [s for s in figures["trace"] if s["t"] >= 60.0]
    withheld = sum(s["soc"] is None for s in late)
    if withheld:
        pytest.xfail(f"SoC withheld in {withheld} of {len(late)} samples after 60 s of flight "
                     f"({figures['readiness']['prediction']}): the estimator of issue 29 items 1-3")
