"""``gcs-pdm sim``: record a flight from a mission file; bad specs are named."""
from __future__ import annotations

import json

import pytest

from gcs_pdm.cli import main
from gcs_pdm.mavlink.mission_files import write_wpl
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.sim.routes import mission_from_enu


def test_record_writes_a_tlog_and_its_truth(tmp_path, capsys):
    mission = tmp_path / "m.waypoints"
    write_wpl(mission, mission_from_enu([(800, 0, 80), (800, 800, 100)]))
    tlog = tmp_path / "flight.tlog"
    code = main(["sim", "--mission", str(mission), "--record", str(tlog), "--fault", "motor:fwd:0.5@leg:2-3",
                 "--degrade", "ULA20:capacity=0.9", "--ground-temp", "30", "--soc", "0.9", "--seed", "7"])
    assert code == 0
    assert "recorded" in capsys.readouterr().out
    truth = json.loads(tlog.with_suffix(".truth.json").read_text())
    assert truth["faults"][0]["motor"] == "fwd" and truth["initial_soc"] == [0.9] * 4
    assert truth["parameters"]["provenance"]["degradation"] == ["ULA20:capacity=0.9,resistance=1"]
    summary = replay_tlog(tlog)
    assert summary.messages > 500 and summary.skipped["bad_crc"] == 0
    assert summary.mapping["frames_by_kind"]["pack"] > 0


@pytest.mark.parametrize("args, needle", [
    (["--fault", "motor:left:0.5@t:3"], "motor must be one of"),
    (["--degrade", "LRF40:capacity=2"], "<= 1"),
    (["--rate", "FOO=3"], "unknown message"),
    (["--wind", "3"], "--wind"),
])
def test_bad_arguments_are_named(args, needle, tmp_path, capsys):
    try:  # docs/cli.md: one prefixed line, exit 2 (argparse's own errors raise SystemExit(2))
        code = main(["sim", "--record", str(tmp_path / "x.tlog")] + args)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "gcs-pdm sim: error: " in err, err
