"""An autopilot's own log (.bin, .ulg) takes the tlog's path through ``gcs-pdm replay``: without
--vehicle the vehicle is derived from the log (the one derivation, gcs_pdm.logs.provisional_vehicle), the
log's battery and ESC instances are the description's packs and motors by instance, the estimate is
traced, and the exit status is docs/mavlink.md's (2 unreadable, 1 nothing diagnosable, 0 success)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# ../shared beside the repository; GCS_PDM_SHARED names it for a checkout elsewhere (a git worktree)
LOGS = Path(os.environ.get("GCS_PDM_SHARED", REPO / ".." / "shared")) / "logs"
BIN = LOGS / "arduplane_sitl_stock.bin"
ULG = LOGS / "px4_sample_log_small.ulg"
needs_logs = pytest.mark.skipif(not BIN.is_file() or not ULG.is_file(), reason=f"shared logs not found under {LOGS}")


def _replay(*args: str, timeout: float = 600) -> tuple[int, dict | None, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    run = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", *args, "--json"], capture_output=True,
                         text=True, cwd=REPO, timeout=timeout, env=env)
    lines = run.stdout.strip().splitlines()
    return run.returncode, (json.loads(lines[-1]) if lines else None), run.stderr


@needs_logs
def test_dataflash_replay_without_a_vehicle_derives_it_from_the_log_and_traces_the_estimate():
    status, summary, err = _replay(str(BIN))
    assert status == 0, err
    about = summary["consumer"]["vehicle"]
    # not the paper's aircraft: the description the log itself gives (3S pack, ESC index 2)
    assert about["source"] == "provisional" and about["name"] == "provisional-arduplane_sitl_stock"
    assert any("3 cells" in n for n in about["notes"]) and any("ESC indices that carried data: 2" in n
                                                               for n in about["notes"])
    assert summary["packs"] == {"battery0": {"instance": 0, "samples": 5004, "cells": None}}
    assert summary["motors"] == {"esc2": 2} and summary["left_out"] == {}
    assert "LLF20" not in json.dumps(summary)
    trace = summary["consumer"]["trace"]
    assert len(trace) >= 15  # 500 s of flight, a sample every 30 s
    assert all(list(s["packs"]) == ["battery0"] and list(s["motors"]) == ["esc2"] for s in trace)
    assert max(s["packs"]["battery0"]["current_a"] for s in trace) > 5.0
    assert max(s["motors"]["esc2"]["rpm"] or 0 for s in trace) > 3000
    # the estimator saw the pack's frames (its readiness speaks of battery0, not of a pack it lacks)
    assert "battery0" in json.dumps(summary["consumer"]["readiness"]) or \
        summary["consumer"]["readiness"]["prediction"] == "ready"


@needs_logs
def test_dataflash_replay_with_a_vehicle_maps_its_packs_by_instance():
    """Before: with --vehicle every pack frame was skipped ("unknown pack 'LLF20'"), no trace, exit 0."""
    status, summary, err = _replay(str(BIN), "--vehicle", "plane-3s")
    assert status == 0, err
    assert "unknown pack" not in err
    assert summary["consumer"]["vehicle"]["source"] == "given"
    assert summary["packs"] == {"battery": {"instance": 0, "samples": 5004, "cells": None}}
    assert summary["motors"] == {"motor": 2}
    trace = summary["consumer"]["trace"]
    assert len(trace) >= 15 and all(list(s["packs"]) == ["battery"] for s in trace)
    assert max(s["packs"]["battery"]["current_a"] for s in trace) > 5.0
    assert summary["consumer"]["estimate"]["counters"].get("unknown_pack", 0) == 0


@needs_logs
def test_ulog_replay_without_a_vehicle_has_both_packs_by_instance():
    status, summary, err = _replay(str(ULG))
    assert status == 0, err
    assert summary["consumer"]["vehicle"]["source"] == "provisional"
    assert {n: p["instance"] for n, p in summary["packs"].items()} == {"battery0": 0, "battery1": 1}
    assert summary["frames_by_kind"]["pack"] == 42
    trace = summary["consumer"]["trace"]
    assert trace and all(sorted(s["packs"]) == ["battery0", "battery1"] for s in trace)
    assert any("ESC" in r for r in summary["not_diagnosed"])  # the log has no ESC telemetry: said


@needs_logs
def test_instances_the_description_does_not_name_are_left_out_and_nothing_to_diagnose_exits_1(tmp_path):
    from gcs_pdm.vehicle.description import dumps
    from gcs_pdm.vehicle.presets import PRESETS

    desc = PRESETS["quad-4s"]
    other = desc.model_copy(update={"name": "elsewhere", "packs": [desc.packs[0].model_copy(
        update={"mavlink_battery_id": 5})], "motors": [m.model_copy(update={"esc_index": 4 + i})
                                                       for i, m in enumerate(desc.motors)]})
    path = tmp_path / "elsewhere.toml"
    path.write_text(dumps(other, "toml"))
    status, summary, err = _replay(str(BIN), "--vehicle", str(path), "--no-diagnose")
    assert status == 1, err
    assert summary["frames_by_kind"].get("pack") is None and summary["frames_by_kind"].get("motor") is None
    assert set(summary["left_out"]) == {"battery instance 0", "ESC instance 2"}
    assert "5004 samples" in summary["left_out"]["battery instance 0"]
    assert any(r.startswith("packs: none of the log's battery instances ([0])") for r in summary["not_diagnosed"])


def test_an_unreadable_autopilot_log_exits_2(tmp_path):
    bad = tmp_path / "garbage.bin"
    bad.write_bytes(b"not a dataflash log at all")
    status, summary, err = _replay(str(bad), "--vehicle", "plane-3s", timeout=120)
    assert status == 2 and summary is None
    assert "not a MAVLink (tlog), DataFlash (.bin) or ULog (.ulg) log" in err  # docs/cli.md


@needs_logs
def test_fit_on_a_dataflash_log_without_a_vehicle_fits_the_vehicle_derived_from_it(tmp_path):
    """One derivation for replay, fit and vehicle init: the fit writes the derived description beside
    the parameter set, and fits the log's pack under its own name (not the paper's LLF20)."""
    b = str(BIN)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    run = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "fit", "battery", "--train", b, "--val", b, "--test", b,
                          "--out", str(tmp_path), "--starts", "1", "--sa-generations", "3", "--lm-max-nfev", "20",
                          "--quiet", "--no-plots"], capture_output=True, text=True, cwd=REPO, timeout=900, env=env)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["pack"] == "battery0" and summary["vehicle"] == "provisional-arduplane_sitl_stock"
    assert "3 cells" in run.stderr and "BATT_CAPACITY" in run.stderr  # the derivation's notes, said
    from gcs_pdm.vehicle.description import load

    desc = load(tmp_path / "vehicle.toml")
    assert [(p.name, p.cells_series, p.capacity_mah) for p in desc.packs] == [("battery0", 3, 3300.0)]
    assert json.loads((tmp_path / "parameters.json").read_text())["packs"].keys() == {"battery0"}
