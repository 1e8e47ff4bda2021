"""Route → MISSION_ITEM_INT list; `gcs-pdm plan` and `gcs-pdm experiment`."""
import json
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm import missions
from gcs_pdm.cli import main
from gcs_pdm.mavlink.mission_files import format_wpl, parse_wpl
from gcs_pdm.models.params import builtin
from gcs_pdm.planning.exact import exact_search
from gcs_pdm.planning.mission import MAV_CMD_DO_CHANGE_SPEED, plan_to_mission
from gcs_pdm.geo import geodetic_from_enu
from gcs_pdm.planning.scenario import Scenario
from gcs_pdm.planning.simulator import VehicleSimulator

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "scenarios"


@pytest.fixture(scope="module")
def planned():
    sc = Scenario.from_json((FIXTURES / "table3_9.json").read_text())
    return sc, exact_search(VehicleSimulator.for_scenario(sc, builtin("paper_si")))


def test_mission_layout_airborne(planned):
    sc, plan = planned
    mp = plan_to_mission(sc, plan)
    items = mp.items
    assert [i.seq for i in items] == list(range(len(items)))
    assert items[0].command == missions.MAV_CMD_NAV_WAYPOINT and items[0].frame == missions.MAV_FRAME_GLOBAL_INT
    assert items[1].command == missions.MAV_CMD_NAV_TAKEOFF
    assert items[-1].command == missions.MAV_CMD_NAV_LAND
    navs = [i for i in items[2:-1] if i.command == missions.MAV_CMD_NAV_WAYPOINT]
    assert len(navs) == len(plan.route)
    for item, idx in zip(navs, plan.route):
        w = sc.waypoints[idx]
        lat, lon = geodetic_from_enu(w.east_m, w.north_m, sc.home.lat_deg, sc.home.lon_deg)
        assert item.x == missions.deg_to_e7(lat) and item.y == missions.deg_to_e7(lon) and item.z == w.alt_m
        assert mp.waypoint_seq[w.number] == item.seq
    # in flight the take-off is skipped: the first new item is current, and only it
    assert mp.current_seq == 2 and items[2].current == 1 and sum(i.current for i in items) == 1
    assert items[2].command in (MAV_CMD_DO_CHANGE_SPEED, missions.MAV_CMD_NAV_WAYPOINT)


def test_mission_on_ground_starts_with_take_off_and_survives_a_file(planned):
    sc, plan = planned
    mp = plan_to_mission(sc, plan, airborne=False)
    assert mp.current_seq == 1 and mp.items[1].current == 1
    assert missions.same_items(parse_wpl(format_wpl(mp.items)), [missions.as_sent(i) for i in mp.items])


def test_speed_items_follow_the_leg_airspeeds(planned):
    sc, _ = planned
    sim = VehicleSimulator.for_scenario(sc, builtin("paper_si"), optimise_airspeed=True)
    plan = exact_search(sim)
    items = plan_to_mission(sc, plan).items
    speeds = [i.param2 for i in items if i.command == MAV_CMD_DO_CHANGE_SPEED]
    assert speeds and all(14.0 < s <= 40.0 for s in speeds)
    # one speed item per change of leg airspeed
    legs = list(plan.leg_airspeed_mps)
    assert len(speeds) == 1 + sum(a != b for a, b in zip(legs, legs[1:]))


def test_cli_plan_json(capsys):
    code = main(["plan", str(FIXTURES / "table3_8.json"), "--planner", "exact", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0 and out["feasible"] and out["planner"] == "exact"
    assert out["reward"] > 0 and out["mission"]["items"][-1]["command"] == missions.MAV_CMD_NAV_LAND
    assert set(out["final_soc"]) == {"LLF20", "ULA20", "LRF40", "URA40"}


def test_cli_plan_text_and_mission_file(capsys, tmp_path):
    wpl = tmp_path / "m.waypoints"
    code = main(["plan", str(FIXTURES / "table3_7.json"), "--planner", "pf", "--particles", "8", "--seed", "3",
                 "--mission", str(wpl)])
    text = capsys.readouterr().out
    assert code == 0 and "route" in text and "feasible: True" in text
    assert wpl.read_text().startswith("QGC WPL 110")


def test_cli_plan_bad_file_is_a_clear_error(capsys, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"name": "x"}')
    assert main(["plan", str(bad)]) == 2
    assert "missing field 'start'" in capsys.readouterr().err  # docs/cli.md: errors on stderr


def test_cli_experiment_table3_small(capsys, tmp_path):
    code = main(["experiment", "table3", "--trials", "2", "--particles", "5", "--stronger-trials", "1",
                 "--learned", str(tmp_path / "none.json")])
    text = capsys.readouterr().out
    assert code == 0
    assert "falls back to the built-in paper_si" in text
    for n in (7, 8, 9, 10):
        assert f"{n} wpts" in text


def test_cli_scenarios_are_the_fixtures(tmp_path, capsys):
    assert main(["experiment", "scenarios", "--out", str(tmp_path)]) == 0
    for n in (7, 8, 9, 10):
        made = json.loads((tmp_path / f"table3_{n}.json").read_text())
        kept = json.loads((FIXTURES / f"table3_{n}.json").read_text())
        start_made, start_kept = made.pop("start"), kept.pop("start")
        assert made == kept
        for key, value in start_kept.items():
            assert start_made[key] == pytest.approx(value, rel=1e-9, abs=1e-5), key


def test_truth_scoring_counts_a_missed_reserve_as_a_failed_plan():
    import itertools

    from gcs_pdm.planning.experiment import score_on_truth
    from gcs_pdm.planning.exact import exact_search
    from gcs_pdm.planning.simulator import FAIL_RESERVE, VehicleSimulator
    from gcs_pdm.sim.truth import true_parameters

    sc = Scenario.from_json((Path(__file__).resolve().parents[1] / "fixtures" / "scenarios" / "table3_9.json").read_text())
    truth = VehicleSimulator.for_scenario(sc, true_parameters())
    routes = [r for k in range(1, 6) for r in itertools.permutations(range(len(sc.waypoints)), k)][::5]
    ev = truth.evaluate(routes)
    score, lost, reserve_missed = score_on_truth(truth, routes)
    assert reserve_missed.any() and ev.feasible.any()
    assert np.all(score[reserve_missed] == 0) and np.all(score[lost] == 0)
    np.testing.assert_array_equal(score[ev.feasible], ev.reward_reached[ev.feasible])
    assert np.all(reserve_missed == (ev.cause == FAIL_RESERVE))
    # the exact optimum under the same rules bounds every score
    assert score.max() <= exact_search(truth).reward
