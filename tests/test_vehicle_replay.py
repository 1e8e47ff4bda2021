"""``gcs-pdm replay`` follows a vehicle description: given (--vehicle) or, with none, the provisional
one derived from the log. Stock ArduPlane SITL with no --vehicle: one pack, SoC in [0, 1] falling
through the flight, a finite (modelled) temperature, the motor's current and rpm from ESC index 2,
a time to cut-off."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
STOCK_TLOG = REPO / ".." / "shared" / "logs" / "arduplane_sitl_stock.tlog"
needs_stock_tlog = pytest.mark.skipif(not STOCK_TLOG.exists(), reason=f"{STOCK_TLOG} not found")


def _replay_json(*args: str) -> dict:
    out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", *args, "--json"],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@needs_stock_tlog
def test_stock_arduplane_replay_without_a_vehicle_derives_one_and_estimates():
    summary = _replay_json(str(STOCK_TLOG))
    consumer = summary["consumer"]
    about = consumer["vehicle"]
    assert about["source"] == "provisional" and about["provisional"]
    assert about["save"].startswith("gcs-pdm vehicle init --from ")
    assert any("ESC indices that carried data: 2" in n for n in about["notes"])
    trace = consumer["trace"]
    assert len(trace) >= 8
    assert all(list(s["packs"]) == ["battery0"] for s in trace)           # one pack
    packs = [s["packs"]["battery0"] for s in trace]
    assert all(p["soc"] is not None and 0.0 <= p["soc"] <= 1.0 for p in packs)
    assert all(p["temperature_c"] is not None and math.isfinite(p["temperature_c"]) for p in packs)
    flying = [p for p in packs if p["current_a"] > 5.0]
    assert len(flying) >= 5
    socs = [p["soc"] for p in flying]
    assert socs[-1] < socs[0] - 0.1                                          # falls through the flight
    assert all(b <= a + 0.01 for a, b in zip(socs, socs[1:]))
    # the motor is ESC index 2's, with its current and rpm
    motors = [s["motors"] for s in trace]
    assert all(list(m) == ["esc2"] for m in motors)
    assert max(m["esc2"]["rpm"] or 0 for m in motors) > 3000
    assert max(m["esc2"]["current_a"] or 0 for m in motors) > 0
    # a time to cut-off while the pack draws, finite and ordered
    lo, med, hi = flying[-1]["time_to_cutoff_s"]
    assert 0 < lo < med < hi < math.inf
    # it is said: readiness and no model mismatch
    assert consumer["readiness"]["prediction"] == "ready"
    assert consumer["readiness"]["motor_diagnosis"].startswith("not diagnosable")


@needs_stock_tlog
def test_replay_with_a_given_vehicle_uses_it():
    summary = _replay_json(str(STOCK_TLOG), "--vehicle", "plane-3s")
    consumer = summary["consumer"]
    assert consumer["vehicle"] == {"name": "plane-3s", "source": "given", "provisional": False, "notes": []}
    assert list(consumer["trace"][-1]["packs"]) == ["battery"]
    assert list(consumer["trace"][-1]["motors"]) == ["motor"]
    assert 0.0 <= consumer["trace"][-1]["packs"]["battery"]["soc"] <= 1.0


def test_replay_with_an_unknown_vehicle_is_a_clear_error(tmp_path):
    path = tmp_path / "x.tlog"
    path.write_bytes(b"")
    out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", str(path), "--vehicle", "nope"],
                         capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 2 and "--vehicle" in out.stderr and "neither a preset" in out.stderr
