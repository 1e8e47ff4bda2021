"""Autopilots' own logs: ArduPilot DataFlash .bin (own bulk reader, checked against pymavlink's
DFReader) and PX4 ULog .ulg (pyulog), into flight tables and telemetry frames; fit and replay CLIs."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.fitting.logs import read_flights
from gcs_pdm.logs.tables import FlightDataError
from gcs_pdm.frames import MotorFrame, PackFrame, StatusTextFrame
from gcs_pdm.logs.dataflash import DataFlashError, read_dataflash
from gcs_pdm.logs.reader import read_log
from gcs_pdm.logs.series import battery_flights, frames, motor_flight
from gcs_pdm.vehicle.presets import PRESETS

LOGS = Path(__file__).resolve().parent.parent / ".." / "shared" / "logs"
BIN = LOGS / "arduplane_sitl_stock.bin"
ULG = LOGS / "px4_sample_log_small.ulg"
pytestmark = pytest.mark.skipif(not BIN.is_file() or not ULG.is_file(), reason=f"shared logs not found under {LOGS}")


@pytest.fixture(scope="module")
def dfreader_messages():
    """The reference decode: pymavlink's DFReader, message by message."""
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(BIN))
    out: dict[str, list] = {"BAT": [], "ESC": [], "GPS": [], "MSG": []}
    while (m := reader.recv_match(type=list(out))) is not None:
        out[m.get_type()].append(m.to_dict())
    return out


def test_bulk_reader_decodes_what_dfreader_decodes(dfreader_messages):
    log = read_dataflash(BIN)
    for name, ref in dfreader_messages.items():
        ours = log.messages(name)
        assert ours[next(iter(ours))].size == len(ref), name
        for col in ref[0]:
            if col == "mavpackettype":
                continue
            want = np.array([r[col] for r in ref])
            if want.dtype.kind in "US":
                assert list(ours[col]) == list(want), (name, col)
            else:
                np.testing.assert_allclose(ours[col], want, rtol=1e-6, atol=1e-9, err_msg=f"{name}.{col}")


def test_garbage_inside_a_log_is_skipped_and_counted(tmp_path):
    data = BIN.read_bytes()
    cut = len(data) // 2
    damaged = tmp_path / "damaged.bin"
    damaged.write_bytes(data[:cut] + b"\x00\xa3\x17garbage" + data[cut:])
    clean, dirty = read_dataflash(BIN), read_dataflash(damaged)
    assert dirty.skipped_bytes >= 10 and clean.skipped_bytes == 0
    # at most the one message the garbage landed in is lost
    assert 0 <= clean.starts.size - dirty.starts.size <= 1
    np.testing.assert_array_equal(clean.messages("BAT")["Volt"][-100:], dirty.messages("BAT")["Volt"][-100:])


def test_a_file_that_is_not_a_dataflash_log_says_so(tmp_path):
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"not a log at all")
    with pytest.raises(DataFlashError, match="not an ArduPilot DataFlash log"):
        read_dataflash(bad)
    with pytest.raises(FlightDataError):
        read_flights(bad, "battery", vehicle=PRESETS["edge540"])


def test_arduplane_battery_and_esc_series(dfreader_messages):
    series = read_log(BIN)
    assert series.autopilot == "ArduPilot" and list(series.batteries) == [0] and list(series.escs) == [2]
    bat = series.batteries[0]
    ref = dfreader_messages["BAT"]
    np.testing.assert_allclose(bat.voltage_v, [r["Volt"] for r in ref], rtol=1e-7)
    np.testing.assert_allclose(bat.current_a, [r["Curr"] for r in ref], rtol=1e-7)
    np.testing.assert_allclose(bat.consumed_mah, [r["CurrTot"] for r in ref], rtol=1e-7)
    assert bat.time_s[0] == 0.0 and np.all(np.diff(bat.time_s) > 0)
    # BAT.Temp is 0 in the log (no sensor): missing, not 0 °C, and said so
    assert all(r["Temp"] == 0.0 for r in ref)
    assert np.isnan(bat.temperature_c).all()
    assert "battery0.temperature_c" in series.missing
    esc = series.escs[2]
    ref_esc = [r for r in dfreader_messages["ESC"] if r["Instance"] == 2]
    np.testing.assert_allclose(esc.rpm, [r["RPM"] for r in ref_esc], rtol=1e-7)
    np.testing.assert_allclose(esc.current_a, [r["Curr"] for r in ref_esc], rtol=1e-7)
    assert np.nanmax(esc.rpm) > 1000
    assert [name for _, name in series.modes] == ["AUTO", "RTL"]
    assert [seq for _, seq, _ in series.commands][:3] == [2, 3, 4]  # MISE: items started in AUTO


def test_arduplane_flight_tables_for_the_fitter():
    # read as the paper's aircraft (edge540): its pack LLF20 is battery instance 0
    edge540 = PRESETS["edge540"]
    (flight,) = read_flights(BIN, "battery", pack="LLF20", vehicle=edge540)
    assert flight.name == "arduplane_sitl_stock_LLF20" and len(flight) == 5004
    assert flight.source["pack"] == "LLF20" and flight.source["instance"] == 0
    assert np.isnan(flight.temperature_c).all()
    assert np.isfinite(flight.voltage_v).all() and np.isfinite(flight.ambient_c).all()
    assert flight.source["missing"]["battery0.temperature_c"].startswith("BAT.Temp is 0")
    # the same flight as the log's own battery table, only named by the description
    (table,) = battery_flights(read_log(BIN), "LLF20")
    np.testing.assert_array_equal(flight.voltage_v, table.voltage_v)
    np.testing.assert_array_equal(flight.current_a, table.current_a)
    # every pack of the description must be in the log (a one-battery log is not the paper's aircraft)
    for pack in ("all", "ULA20"):
        with pytest.raises(FlightDataError, match="no battery instance 1 for pack ULA20.*it has instances 0"):
            read_flights(BIN, "battery", pack=pack, vehicle=edge540)
    with pytest.raises(FlightDataError, match="unknown pack 'main'"):
        read_flights(BIN, "battery", pack="main", vehicle=edge540)
    (motor,) = read_flights(BIN, "motor", vehicle=edge540)
    assert motor.source["escs"] == [2] and np.nanmax(motor.current_a) > 0 and np.nanmean(motor.temperature_c) > 0


def test_arduplane_frames_are_the_live_frames():
    out = frames(read_log(BIN))
    packs = [f for f in out if isinstance(f, PackFrame)]
    assert len(packs) == 5004 and all(f.temperature_c is None for f in packs)
    assert all(f.pack == "LLF20" and f.voltage_v > 9 for f in packs)
    motors = [f for f in out if isinstance(f, MotorFrame)]
    assert {f.motor for f in motors} == {"esc2"} and motors[-1].rpm is not None
    assert any(isinstance(f, StatusTextFrame) and f.text.startswith("ArduPlane") for f in out)
    assert all(a.time_s <= b.time_s for a, b in zip(out, out[1:]))


def test_px4_ulog_two_batteries_at_a_low_rate():
    series = read_log(ULG)
    assert series.autopilot == "PX4" and sorted(series.batteries) == [0, 1]
    cells = {i: b.cells for i, b in series.batteries.items()}
    assert cells == {0: 6, 1: 12}
    for i, b in series.batteries.items():
        assert 10 <= b.time_s.size <= 100  # a low logging rate
        per_cell = np.nanmedian(b.voltage_v) / b.cells
        assert 3.3 < per_cell < 4.3, (i, per_cell)
        assert np.isnan(b.temperature_c).all()
    assert series.ambient is not None and np.isfinite(series.ambient[1]).all()
    flights = battery_flights(series)
    assert [f.name for f in flights] == ["px4_sample_log_small_LLF20", "px4_sample_log_small_ULA20"]
    with pytest.raises(FlightDataError, match="no ESC telemetry"):
        motor_flight(series)


def _cli(*args, timeout=300):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parent.parent) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "gcs_pdm.cli", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.mark.parametrize("path, packs", [(BIN, 5004), (ULG, 42)])
def test_replay_cli_accepts_autopilot_logs(path, packs):
    run = _cli("replay", str(path), "--json", "--no-diagnose")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["frames_by_kind"]["pack"] == packs
    assert any(k.endswith("temperature_c") for k in summary["missing"])


@pytest.mark.slow
def test_voltage_only_fit_of_the_stock_arduplane_battery(tmp_path):
    """Stock ArduPilot logs no pack temperature: the circuit is fitted, the thermal part is reported
    as not fitted with its reason, and the test error is the voltage's."""
    b = str(BIN)
    run = _cli("fit", "battery", "--train", b, "--val", b, "--test", b, "--out", str(tmp_path), "--starts", "1",
               "--quiet", "--no-plots", timeout=600)
    assert run.returncode == 0, run.stderr
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["thermal"]["fitted"] is False and "temperature" in result["thermal"]["reason"]
    test_v = result["errors"]["learned"]["test"]["overall"]["voltage"]["rmse"]
    assert result["errors"]["learned"]["test"]["overall"]["temperature"]["rmse"] is None  # not measured: no number
    assert test_v is not None and 0 < test_v < 0.25
