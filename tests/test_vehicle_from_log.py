"""A provisional vehicle description from an autopilot's own log (issue 14): DataFlash and ULog are
read by gcs_pdm.logs and turned into the same observations a tlog gives, so one derivation serves
every format."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from gcs_pdm.cli import main
from gcs_pdm.logs.reader import read_log
from gcs_pdm.vehicle.description import VehicleError, load
from gcs_pdm.logs.provisional_vehicle import airframe_of_log, log_observations, observe_file, observe_log
from gcs_pdm.mavlink.provisional_vehicle import observe_tlog
from gcs_pdm.vehicle.provisional import derive_provisional

LOGS = Path(__file__).parents[1] / ".." / "shared" / "logs"
STOCK_BIN = LOGS / "arduplane_sitl_stock.bin"
STOCK_TLOG = LOGS / "arduplane_sitl_stock.tlog"
PX4_ULG = LOGS / "px4_sample_log_small.ulg"
pytestmark = pytest.mark.skipif(not (STOCK_BIN.exists() and PX4_ULG.exists()), reason=f"{LOGS} not found")


@pytest.fixture(scope="module")
def stock():
    return read_log(STOCK_BIN)


def test_the_stock_arduplane_dataflash_log(stock):
    desc, notes = observe_log(STOCK_BIN)
    assert desc.provisional and desc.name == "provisional-arduplane_sitl_stock"
    # the log says what it is: VER names ArduPlane, PARM has Q_ENABLE off — not assumed
    assert desc.airframe.type == "fixed_wing"
    assert "ArduPlane V4.7.0-dev" in notes[0] and "Q_ENABLE off" in notes[0] and "ASSUMED" not in notes[0]
    assert [(p.mavlink_battery_id, p.cells_series, p.reports_temperature) for p in desc.packs] == [(0, 3, False)]
    assert desc.packs[0].capacity_mah == 3300.0  # SITL's BATT_CAPACITY, read from PARM
    assert any("BATT_CAPACITY parameter" in n for n in notes)
    assert [m.esc_index for m in desc.motors] == [2]  # the one motor: ESC instance 2, the others idle
    assert desc.motors[0].readings.current and desc.motors[0].readings.rpm


def test_one_derivation_for_the_tlog_and_the_dataflash_log_of_one_session():
    """The vehicle's own log and the tlog of the same flight describe the same vehicle."""
    from_bin, _ = observe_file(STOCK_BIN)
    from_tlog, _ = observe_file(STOCK_TLOG)
    assert from_tlog == observe_tlog(STOCK_TLOG)[0].model_copy(update={"name": from_tlog.name})
    shape = lambda d: (d.airframe.type, [(p.mavlink_battery_id, p.cells_series, p.reports_temperature)  # noqa: E731
                                         for p in d.packs], [(m.esc_index, m.readings) for m in d.motors])
    assert shape(from_bin) == shape(from_tlog)


def test_the_px4_ulog_with_two_packs():
    desc, notes = observe_log(PX4_ULG)
    assert [(p.mavlink_battery_id, p.cells_series) for p in desc.packs] == [(0, 6), (1, 12)]
    assert [p.capacity_mah for p in desc.packs] == [30000.0, 6000.0]  # BAT1_CAPACITY, BAT2_CAPACITY
    assert not any(p.reports_temperature for p in desc.packs)
    # MAV_TYPE 22 (a standard VTOL): its fixed-wing cruise, and the notes say what is not modelled
    assert desc.airframe.type == "fixed_wing"
    assert any("MAV_TYPE 22 is a VTOL" in n for n in notes)
    assert any("the log's MAV_TYPE parameter (22)" in n for n in notes)
    assert any("no ESC telemetry" in n for n in notes)  # the log has no esc_status


def test_an_airframe_the_log_does_not_name_is_said_to_be_assumed(stock):
    bare = dataclasses.replace(stock, firmware=None, build=None, texts=[], parameters={})
    mav_type, source = airframe_of_log(bare)
    assert mav_type == 1 and "ASSUMED" in source
    copter = dataclasses.replace(stock, firmware="ArduCopter V4.6.0", build=2, parameters={"FRAME_CLASS": 2.0, "BATT_CAPACITY": 3300.0})
    desc, notes = derive_provisional(log_observations(copter))
    assert desc.airframe.type == "multirotor" and len(desc.motors) == 1  # ESC 2 reports; FRAME_CLASS 2 is a hexa
    assert airframe_of_log(copter)[0] == 13
    with pytest.raises(VehicleError, match="FRAME_CLASS"):
        airframe_of_log(dataclasses.replace(copter, parameters={}))
    quadplane = dataclasses.replace(stock, parameters={**stock.parameters, "Q_ENABLE": 1.0})
    assert airframe_of_log(quadplane)[0] == 22


def test_a_high_voltage_pack_spans_several_voltage_entries(stock):
    """BATTERY_STATUS.voltages entries are uint16 mV: a 14S pack (58.8 V) spans two, as ArduPilot
    sends it, and the derivation reads the sum."""
    b = stock.batteries[0]
    hv = dataclasses.replace(stock, batteries={0: dataclasses.replace(b, voltage_v=b.voltage_v * 58.8 / 12.6)})
    desc, _ = derive_provisional(log_observations(hv))
    assert desc.packs[0].cells_series == 14


def test_cli_init_from_a_dataflash_and_a_ulog(tmp_path, capsys):
    for log, packs in ((STOCK_BIN, 1), (PX4_ULG, 2)):
        out = tmp_path / f"{log.stem}.toml"
        assert main(["vehicle", "init", "--from", str(log), "--out", str(out)]) == 0
        assert "note: airframe from the log's" in capsys.readouterr().err
        assert len(load(out).packs) == packs
        assert main(["vehicle", "check", str(out)]) == 0
        assert f"{packs} pack(s)" in capsys.readouterr().out
    assert main(["vehicle", "init", "--from", str(tmp_path / "none.bin"), "--out", str(tmp_path / "x.toml")]) == 2
    assert "none.bin" in capsys.readouterr().err
