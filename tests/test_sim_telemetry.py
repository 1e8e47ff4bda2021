"""What the vehicle puts on the wire: scaling, quantisation, rates, drop-outs, simulated time."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.models.params import BUILTIN_SETS, builtin
from gcs_pdm.sim.model import SimConfig, VehicleModel
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.sim.telemetry import DEFAULT_RATES, SensorNoise, Telemetry, TelemetryConfig
from gcs_pdm.sim.truth import true_parameters

EXACT = TelemetryConfig(noise=SensorNoise(0, 0, 0, 0, 0, 0, 0), drop_rate=0.0)


def wire(msgs):
    """Encode and decode again, as a receiver would see them."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for m in msgs:
        buf = m.pack(mav)
        out.append(mav.decode(bytearray(buf)))
    return out


def flying_model(seconds=60.0):
    m = VehicleModel(SimConfig(mission=tuple(mission_from_enu([(2000, 0, 150)]))))
    while m.time_s < seconds:
        m.step()
    return m


def test_values_are_scaled_and_quantised_as_the_link_expects():
    m = flying_model()
    s = m.state()
    tel = Telemetry(EXACT)
    by_type: dict = {}
    for msg in wire(tel.periodic(s)):
        by_type.setdefault(msg.get_type(), []).append(msg)
    for b in by_type["BATTERY_STATUS"]:
        i = b.id
        assert b.voltages[0] == round(s.pack_voltage_v[i] * 1000) and list(b.voltages[1:]) == [65535] * 9
        assert b.current_battery == round(s.pack_current_a[i] * 100)
        assert b.temperature == round(s.pack_temp_c[i] * 100)
        assert b.battery_remaining == round(100 * s.pack_soc[i])
    (esc,) = by_type["ESC_TELEMETRY_1_TO_4"]
    assert list(esc.current[:2]) == [round(c * 100) for c in s.motor_current_a]
    assert list(esc.temperature[:2]) == [round(t) for t in s.motor_temp_c]
    assert esc.rpm[0] == esc.rpm[1] == round(s.rpm) > 1000
    assert list(esc.voltage[:2]) == [round(v * 100) for v in s.motor_voltage_v]
    (sp,) = by_type["SCALED_PRESSURE"]
    assert sp.temperature == round(s.ambient_c * 100) and sp.time_boot_ms == round(s.time_s * 1000)
    (gp,) = by_type["GLOBAL_POSITION_INT"]
    assert gp.relative_alt == round(s.alt_m * 1000) and gp.lat == round(s.lat_deg * 1e7)
    (hb,) = by_type["HEARTBEAT"]
    assert hb.custom_mode == 10 and hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink2.MAV_STATE_ACTIVE


def test_rates_drop_outs_and_outages():
    m = flying_model(5.0)
    cfg = TelemetryConfig(drop_rate=0.2, outages=((50.0, 10.0),))
    tel = Telemetry(cfg, seed=1)
    counts: dict = {}
    in_outage = 0
    for _ in range(1000):  # 100 s of 0.1 s ticks
        m.step()
        for msg in tel.periodic(m.state()):
            counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
            if 50.0 <= m.time_s < 60.0:
                in_outage += 1
    assert in_outage == 0
    sent = sum(counts.values())
    expected = sum(hz * 90 * (4 if n == "BATTERY_STATUS" else 1) for n, hz in DEFAULT_RATES.items())
    assert sent == pytest.approx(0.8 * expected, rel=0.06)
    assert tel.dropped == pytest.approx(0.2 * expected + expected / 9, rel=0.15)
    assert counts["BATTERY_STATUS"] == pytest.approx(0.8 * 4 * 2.0 * 90, rel=0.1)


def test_the_hidden_truth_is_none_of_the_shipped_sets():
    truth = true_parameters()
    for name in BUILTIN_SETS:
        other = builtin(name)
        assert not np.allclose(truth.pack_matrix(), other.pack_matrix(), rtol=0.01)
    assert not np.allclose(true_parameters(1).pack_matrix(), truth.pack_matrix())


def test_wind_is_crabbed_into_and_the_mission_still_lands():
    m = VehicleModel(SimConfig(mission=tuple(mission_from_enu([(1500, 0, 100), (1500, 1500, 100)])),
                               wind_en_mps=(0.0, 6.0)))
    samples = []
    while not m.finished and m.time_s < 1800:
        m.step()
        s = m.state()
        if s.current_seq == 2 and s.alt_m > 90 and 1500 - s.east_m > 200:  # heading east; the air moves north
            track = np.arctan2(s.vel_east_mps, s.vel_north_mps)
            bearing = np.arctan2(1500 - s.east_m, -s.north_m)
            samples.append((track - bearing, s.groundspeed_mps, s.airspeed_mps, s.heading_deg))
    assert m.state().landed
    err, g, a, heading = np.array(samples[-50:]).T
    assert np.all(np.abs(err) < np.radians(2))  # the ground track points at the waypoint
    assert np.all((heading > 95) & (heading < 125))  # the nose turns into the wind, which blows from the south
    assert np.all(g < a - 0.3)  # and the ground speed is below the airspeed
