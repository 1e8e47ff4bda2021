"""The recorded fixture flights: complete, small, decodable by the link, and true to their manifest."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.frames import AmbientFrame, MotorFrame, PackFrame
from gcs_pdm.mavlink.mission_files import read_wpl
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES, ParameterSet
from gcs_pdm.sim.record import fly
from gcs_pdm.sim.truth import true_parameters

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
FLIGHTS = FIXTURES / "flights"
MANIFEST = json.loads((FLIGHTS / "manifest.json").read_text())
BY_NAME = {f["name"]: f for f in MANIFEST["flights"]}


def frames_of(name: str) -> list:
    out: list = []
    summary = replay_tlog(FLIGHTS / BY_NAME[name]["tlog"], frame_consumer=out.append)
    assert summary.skipped == {"bad_crc": 0, "unknown_msgid": 0, "garbage_bytes": 0, "truncated_tail_bytes": 0}
    return out


def test_the_set_is_complete_varied_and_small():
    learn = [f for f in MANIFEST["flights"] if not f["fault_spec"]]
    faulty = [f for f in MANIFEST["flights"] if f["fault_spec"]]
    assert len(learn) >= 12 and len(faulty) >= 3
    minutes = [f["duration_s"] / 60 for f in learn]
    assert min(minutes) >= 10 and max(minutes) <= 31 and max(minutes) - min(minutes) > 12
    temps = [f["ground_temp_c"] for f in learn]
    assert max(temps) - min(temps) > 25
    assert all(f["landed"] and not f["failed"] for f in learn)
    split = MANIFEST["split"]
    assert (len(split["train"]), len(split["validation"]), len(split["test"])) == (8, 2, 2)
    assert sorted(sum(split.values(), [])) == sorted(f["name"] for f in learn)
    total = sum((FLIGHTS / f["tlog"]).stat().st_size for f in MANIFEST["flights"])
    assert total < 6e6
    # the truth file is the hidden truth, readable as a parameter set
    truth = ParameterSet.from_json((FLIGHTS / MANIFEST["truth_parameters_file"]).read_text())
    # equal to the last bits: numpy's exp/log may round one ULP differently on another CPU or build
    np.testing.assert_allclose(truth.pack_matrix(), true_parameters(MANIFEST["truth_seed"]).pack_matrix(),
                               rtol=1e-13, atol=0)


def test_fault_flights_fault_between_waypoints_2_and_3_and_one_fails():
    faulty = [f for f in MANIFEST["flights"] if f["fault_spec"]]
    for f in faulty:
        (fault,) = f["faults"]
        assert fault["waypoint_leg"] == [2, 3]
        reached = dict((seq, t) for seq, t in f["reached"])
        assert reached[fault["last_reached_seq"]] < fault["time_s"]
        if fault["current_seq"] in reached:
            assert fault["time_s"] < reached[fault["current_seq"]]
    failed = [f for f in faulty if f["failed"]]
    assert failed and all("cut-off" in f["failure"] or "temperature" in f["failure"] for f in failed)


def test_fault_flight_shows_the_healthy_motor_loaded_in_the_telemetry():
    f = BY_NAME["fault_01"]
    fault = f["faults"][0]
    healthy, dead = ("fwd", "aft") if fault["motor"] == "aft" else ("aft", "fwd")
    motors = [fr for fr in frames_of("fault_01") if isinstance(fr, MotorFrame)]
    t0 = fault["time_s"]

    def mean(name, lo, hi):
        return np.mean([fr.current_a for fr in motors if fr.motor == name and lo < fr.time_s < hi])
    assert mean(healthy, t0 + 2, t0 + 30) > 3 * mean(dead, t0 + 2, t0 + 30)
    assert abs(mean(healthy, t0 - 30, t0 - 2) - mean(dead, t0 - 30, t0 - 2)) < 1.0

    def temp(name, at):
        return np.mean([fr.temperature_c for fr in motors if fr.motor == name and abs(fr.time_s - at) < 10])
    # the healthy motor warms, the faulted one does not keep up with it
    assert temp(healthy, t0 + 300) - temp(healthy, t0) > 2.0
    assert temp(healthy, t0 + 300) - temp(dead, t0 + 300) > 4.0


@pytest.mark.parametrize("name", ["learn_11", "fault_02"])
def test_kernel_with_manifest_truth_reproduces_the_recorded_voltages(name):
    """Decoded currents + the manifest's initial SoC + the truth parameters → the decoded voltages."""
    f = BY_NAME[name]
    frames = frames_of(name)
    params = true_parameters(MANIFEST["truth_seed"]).pack_matrix()
    amb = [(fr.time_s, fr.temperature_c) for fr in frames if isinstance(fr, AmbientFrame)]
    ta, va = np.array(amb).T
    for i, pack in enumerate(PACK_NAMES):
        pf = [fr for fr in frames if isinstance(fr, PackFrame) and fr.pack == pack]
        t = np.array([fr.time_s for fr in pf])
        v = np.array([fr.voltage_v for fr in pf])
        cur = np.array([fr.current_a for fr in pf])
        x0 = kernel.initial_pack_state(params[i:i + 1], f["initial_soc"][i], f["ground_temp_c"])
        dt = np.diff(np.concatenate([[0.0], t]))
        out = kernel.simulate_packs(params[i:i + 1], x0, dt, cur, np.interp(t, ta, va))
        err = np.abs(out.voltage[0] - v)
        assert np.median(err) < 0.05, (pack, np.median(err))
        assert np.percentile(err, 99) < 0.3


def test_missions_beside_the_tlogs_read_back():
    for f in MANIFEST["flights"]:
        items = read_wpl(FLIGHTS / f["mission_file"])
        assert items[1].command == 22 and items[-1].command == 21
        assert max(seq for seq, _ in f["reached"]) <= len(items) - 1


def test_regenerating_a_flight_gives_the_committed_bytes(tmp_path):
    sys.path.insert(0, str(FIXTURES))
    import make_fixtures  # noqa: PLC0415 - the script is not a package module

    built = {name: (cfg, tel) for name, cfg, tel, _ in make_fixtures.build()}
    cfg, tel = built["learn_11"]
    fly(cfg, tel, tmp_path / "again.tlog")
    assert (tmp_path / "again.tlog").read_bytes() == (FLIGHTS / "learn_11.tlog").read_bytes()
