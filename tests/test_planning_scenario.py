"""Scenario format: JSON round trip, live construction, clear errors."""
import json
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.models.params import builtin
from gcs_pdm.models.powertrain import MotorFault, PowertrainState
from gcs_pdm.geo import enu_from_geodetic, geodetic_from_enu
from gcs_pdm.planning.scenario import Home, PlanLimits, Scenario, ScenarioError, Waypoint

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "scenarios"


def test_fixture_round_trips_through_json():
    text = (FIXTURES / "table3_10.json").read_text()
    sc = Scenario.from_json(text)
    again = Scenario.from_json(sc.to_json())
    assert again == sc
    assert [w.number for w in sc.waypoints] == list(range(3, 11))
    assert sc.faults == (MotorFault("aft", 0.7),)
    assert sc.visited == (1, 2)


def test_geodetic_waypoints_convert_about_home():
    home = Home(lat_deg=47.0, lon_deg=8.0)
    lat, lon = geodetic_from_enu(1234.0, -2345.0, home.lat_deg, home.lon_deg)
    e, n = enu_from_geodetic(lat, lon, home.lat_deg, home.lon_deg)
    assert e == pytest.approx(1234.0, abs=1e-6) and n == pytest.approx(-2345.0, abs=1e-6)
    data = json.loads((FIXTURES / "table3_7.json").read_text())
    data["home"].update(lat_deg=47.0, lon_deg=8.0)
    data["waypoints"][0] = {"number": 3, "lat_deg": lat, "lon_deg": lon, "alt_m": 100, "reward": 5}
    sc = Scenario.from_dict(data)
    assert sc.waypoints[0].east_m == pytest.approx(1234.0, abs=1e-3)
    assert sc.waypoints[0].airspeed_mps == 25.0


def test_from_live_keeps_the_estimated_pack_states():
    ps = builtin("paper_si")
    st = PowertrainState.full(ps, 25.0, 0.6)
    wps = [Waypoint(1, 100.0, 200.0, 100.0, 10.0)]
    sc = Scenario.from_live(st, [MotorFault("fwd", 0.3)], wps, (10.0, 20.0, 80.0), Home(),
                            PlanLimits(landing_reserve_soc=0.1), params=ps, time_s=123.0)
    back = Scenario.from_json(sc.to_json())
    np.testing.assert_allclose(back.start.powertrain(back.parameter_set()).pack_state, st.pack_state)
    assert back.parameter_set().pack_matrix().tolist() == ps.pack_matrix().tolist()
    assert back.limits.landing_reserve_soc == 0.1 and back.start.time_s == 123.0


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("start"), "missing field 'start'"),
    (lambda d: d["start"].update(pack_soc=[1.2, 0.5, 0.5, 0.5]), "pack_soc"),
    (lambda d: d["limits"].update(speed=3), "limits: unknown field"),
    (lambda d: d["waypoints"][0].update(reward=-1), "reward"),
    (lambda d: d["waypoints"][1].update(number=d["waypoints"][0]["number"]), "unique"),
    (lambda d: d["faults"][0].update(motor="left"), "motor"),
    (lambda d: d.update(params="no_such_set"), "no built-in parameter set"),
    (lambda d: d["waypoints"][0].pop("east_m"), "east_m"),
    (lambda d: d.update(version=2), "version"),
    (lambda d: d.update(format="qgc-plan"), "format"),
])
def test_bad_scenarios_name_the_field(edit, message):
    data = json.loads((FIXTURES / "table3_7.json").read_text())
    edit(data)
    with pytest.raises(ScenarioError, match=message):
        Scenario.from_dict(data).flown_vehicle()  # its vehicle resolved: faults by the paper's motors


def test_not_json_is_a_clear_error():
    with pytest.raises(ScenarioError, match="not JSON"):
        Scenario.from_json("{nope")
