"""The speed work of issue 18 must not change what users see: today's outputs, recorded by
``tests/reference/make_reference.py`` before any optimisation, against the current code.

Tolerances (the optimisations change summation order only, so differences are round-off that a
Kalman filter damps, not amplifies):
- faults: same types, components, raise/clear/update times exactly; magnitudes within 1e-3;
- final estimate: SoC within 2e-4 (it is stored to 4 decimals), temperatures within 0.02 °C,
  voltages within 2 mV; counters equal;
- pack-health fits: within 1e-3 relative (or 1e-6 absolute);
- synthetic flight estimates every 60 s: SoC within 1e-6, temperature within 1e-5 °C;
- Monte Carlo quantiles (fixed seed): within 1e-6 relative.
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np
import pytest

REF = Path(__file__).resolve().parent / "reference"
sys.path.insert(0, str(REF))  # the reference generator; tests/ is not a package
import make_reference  # noqa: E402

REPLAY = json.loads((REF / "replay_fixture_flights.json").read_text())


def _close_tree(got, want, rel, abs_, path=""):
    if isinstance(want, dict):
        assert set(got) == set(want), path
        for k in want:
            _close_tree(got[k], want[k], rel, abs_, f"{path}.{k}")
    elif isinstance(want, list):
        assert len(got) == len(want), path
        for i, (g, w) in enumerate(zip(got, want)):
            _close_tree(g, w, rel, abs_, f"{path}[{i}]")
    elif isinstance(want, float) and isinstance(got, (int, float)):
        assert got == pytest.approx(want, rel=rel, abs=abs_), path
    else:
        assert got == want, path


@pytest.mark.parametrize("flight", sorted(REPLAY))
def test_replay_of_fixture_flight_gives_todays_faults_and_estimate(flight):
    logging.disable(logging.WARNING)
    try:
        got = make_reference.replay_outputs(make_reference.FLIGHTS / f"{flight}.tlog")
    finally:
        logging.disable(logging.NOTSET)
    want = REPLAY[flight]
    assert got["messages"] == want["messages"] and got["frames_by_kind"] == want["frames_by_kind"]
    assert [(f["type"], f["component"], f["time_s"], f["active"], f["updated_s"], f["cleared_s"]) for f in got["faults"]] == \
           [(f["type"], f["component"], f["time_s"], f["active"], f["updated_s"], f["cleared_s"]) for f in want["faults"]]
    for g, w in zip(got["faults"], want["faults"]):
        assert g["magnitude"] == pytest.approx(w["magnitude"], abs=1e-3)
    assert [(e["event"], e["time_s"], e["type"], e["component"]) for e in got["events"]] == \
           [(e["event"], e["time_s"], e["type"], e["component"]) for e in want["events"]]
    ge, we = got["estimate"], want["estimate"]
    assert ge["time_s"] == we["time_s"] and ge["counters"] == we["counters"]
    for name, pack in we["packs"].items():
        g = ge["packs"][name]
        assert g["soc"] == pytest.approx(pack["soc"], abs=2e-4)
        assert g["temperature_c"] == pytest.approx(pack["temperature_c"], abs=0.02)
        assert g["voltage_v"] == pytest.approx(pack["voltage_v"], abs=0.002)
    for name, motor in we["motors"].items():
        assert ge["motors"][name]["temperature_c"] == pytest.approx(motor["temperature_c"], abs=0.02)
    _close_tree(got["pack_health"], want["pack_health"], 1e-3, 1e-6)
    _close_tree(got["prognosis_latest"], want["prognosis_latest"], 1e-6, 1e-9)


def test_estimates_over_a_synthetic_flight_are_todays():
    want = json.loads((REF / "estimates_synthetic.json").read_text())
    got = make_reference.synthetic_estimates()
    assert got["frames"] == want["frames"] and got["counters"] == want["counters"]
    assert len(got["samples"]) == len(want["samples"])
    for g, w in zip(got["samples"], want["samples"]):
        assert g["time_s"] == w["time_s"]
        np.testing.assert_allclose(g["soc"], w["soc"], atol=1e-6)
        np.testing.assert_allclose(g["soc_sd"], w["soc_sd"], atol=1e-6)
        np.testing.assert_allclose(g["pack_temp_c"], w["pack_temp_c"], atol=1e-5)
        np.testing.assert_allclose(g["pack_voltage_v"], w["pack_voltage_v"], atol=1e-6)
        np.testing.assert_allclose(g["motor_temp_c"], w["motor_temp_c"], atol=1e-5)


def test_monte_carlo_quantiles_with_a_fixed_seed_are_todays():
    want = json.loads((REF / "mc_quantiles.json").read_text())
    _close_tree(make_reference.mc_quantiles(), want, 1e-6, 1e-9)


# ---- `gcs-pdm replay FILE --json` as users see it (issue 18's whole-process figure) -----------------
# Recorded before the replay's speed work (tests/reference/replay_cli/, one file per tlog, the run's
# own timing and path left out). The 100,000-message tlog of benchmarks/bench_replay.py is compared
# too when that benchmark has cached it (it takes ~40 s to generate).
# Tolerances: every string, count and flag exactly; fault and event times, frame times, trace
# times exactly (1e-9); other numbers within 2e-4 absolute (the trace and estimate are printed to
# 4 decimals: one rounding step) or 1e-6 relative; pack-health fits and their evidence 1e-3 relative.

import tempfile  # noqa: E402

from gcs_pdm.cli import main as cli_main  # noqa: E402

REPLAY_CLI = REF / "replay_cli"
BENCH_TLOG = Path(tempfile.gettempdir()) / "gcs_pdm_bench_typical_100k_v1.tlog"
_VOLATILE = ("path", "elapsed_s", "messages_per_s")
_LOOSE = ("pack_health", "evidence", "magnitude", "confidence")


def _cli_tlogs() -> dict[str, Path]:
    out = {p.stem: p for p in sorted((REF.parents[1] / "fixtures" / "flights").glob("*.tlog"))}
    out["arduplane_sitl_stock"] = REF.parents[2] / "shared" / "logs" / "arduplane_sitl_stock.tlog"
    if BENCH_TLOG.exists():
        out[BENCH_TLOG.stem] = BENCH_TLOG
    return out


def _same(got, want, path: str = "", loose: bool = False) -> None:
    if isinstance(want, dict):
        assert sorted(got) == sorted(want), path
        for k in want:
            _same(got[k], want[k], f"{path}.{k}", loose or k in _LOOSE)
    elif isinstance(want, list):
        assert len(got) == len(want), path
        for i, (g, w) in enumerate(zip(got, want)):
            _same(g, w, f"{path}[{i}]", loose)
    elif isinstance(want, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        if path.endswith(("time_s", "_s]", "cleared_s", "updated_s")) and "time_to_cutoff" not in path:
            assert got == pytest.approx(want, rel=0, abs=1e-9), path
        elif loose:
            assert got == pytest.approx(want, rel=1e-3, abs=1e-6), path
        else:
            assert got == pytest.approx(want, rel=1e-6, abs=2e-4), path
    else:
        assert got == want, path


@pytest.mark.parametrize("name", sorted(_cli_tlogs()))
def test_replay_command_json_is_todays(name, capsys):
    path = _cli_tlogs()[name]
    want = json.loads((REPLAY_CLI / f"{name}.json").read_text())
    logging.disable(logging.WARNING)
    try:
        status = cli_main(["replay", str(path), "--json"])
    finally:
        logging.disable(logging.NOTSET)
    got = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert status in (0, 1)
    for k in _VOLATILE:
        got.pop(k)
    about_got, about_want = (got.get("consumer") or {}).get("vehicle", {}), (want.get("consumer") or {}).get("vehicle", {})
    if "save" in about_want:  # names the path the replay was given
        assert about_got.pop("save") == f"gcs-pdm vehicle init --from {path} --out vehicle.toml"
        about_want.pop("save")
    _same(got, want)
