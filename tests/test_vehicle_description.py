"""The vehicle description: validation naming the field, presets, TOML/JSON round trip, the
model inputs (edge540 == the paper_si construction), the provisional derivation, the CLI."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.cli import main
from gcs_pdm.models import kernel, multirotor
from gcs_pdm.models.params import default_set
from gcs_pdm.vehicle.description import VehicleError, dumps, from_dict, load, parse
from gcs_pdm.vehicle.presets import resolve
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS
from gcs_pdm.mavlink.provisional_vehicle import observe_tlog
from gcs_pdm.vehicle.provisional import CapacityUnknown, derive_provisional

STOCK_TLOG = Path(__file__).parents[1] / ".." / "shared" / "logs" / "arduplane_sitl_stock.tlog"
needs_stock_tlog = pytest.mark.skipif(not STOCK_TLOG.exists(), reason=f"{STOCK_TLOG} not found")


def test_presets_exist_and_round_trip_toml_and_json():
    assert {"edge540", "plane-3s", "quad-4s", "quad-6s", "hex-6s"} <= set(PRESETS)
    for desc in PRESETS.values():
        assert parse(dumps(desc, "toml"), "toml") == desc
        assert parse(dumps(desc, "json"), "json") == desc
    assert PRESETS["hex-6s"].feed_kind() == "packs in parallel"
    assert len(PRESETS["hex-6s"].motors) == 6
    assert PRESETS["edge540"].feed_kind() == "series strings"
    plane = PRESETS["plane-3s"]
    assert [(p.mavlink_battery_id, p.cells_series) for p in plane.packs] == [(0, 3)]
    assert [m.esc_index for m in plane.motors] == [2]


def _edited(preset: str, **path_values) -> dict:
    data = PRESETS[preset].to_dict()
    for path, value in path_values.items():
        node = data
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[int(k)] if k.isdigit() else node[k]
        node[keys[-1]] = value
    return data


@pytest.mark.parametrize("edit, field", [
    ({"packs__0__cells_series": 0}, "packs[0].cells_series"),
    ({"packs__0__capacity_mah": -5}, "packs[0].capacity_mah"),
    ({"airframe__cd0": 3.0}, "airframe.cd0"),
    ({"motors__1__esc_index": 0}, "motors: two motors share an esc_index"),
    ({"buses__0__packs": ["LLF20", "NOPE"]}, "buses[0].packs: no pack 'NOPE'"),
    ({"buses__1__motors": ["fwd"]}, "motor 'fwd' must be on exactly one bus"),
    ({"landing_reserve": 1.5}, "landing_reserve"),
])
def test_errors_name_the_field(edit, field):
    with pytest.raises(VehicleError) as err:
        from_dict(_edited("edge540", **edit))
    assert field in str(err.value)


def test_unknown_field_and_bad_airframe_type_are_named(tmp_path):
    data = PRESETS["quad-4s"].to_dict()
    data["packs"][0]["volts"] = 3
    with pytest.raises(VehicleError, match=r"packs\[0\]\.volts"):
        from_dict(data)
    bad = tmp_path / "v.toml"
    bad.write_text(dumps(PRESETS["quad-4s"]).replace('type = "multirotor"', 'type = "blimp"'))
    with pytest.raises(VehicleError, match="v.toml: airframe"):
        load(bad)
    with pytest.raises(VehicleError, match="neither a preset"):
        resolve(tmp_path / "missing.toml")


def test_edge540_model_inputs_equal_the_paper_si_construction():
    inputs = model_inputs(PRESETS["edge540"])
    ps = default_set()
    np.testing.assert_array_equal(inputs.pack_matrix, ps.pack_matrix())
    np.testing.assert_array_equal(inputs.motor_matrix, np.stack([ps.motor_vector()] * 2))
    np.testing.assert_array_equal(inputs.bus_of_pack, kernel.STRING_OF_PACK)
    np.testing.assert_array_equal(inputs.bus_of_motor, [0, 1])
    assert inputs.pack_names == ("LLF20", "ULA20", "LRF40", "URA40")
    assert inputs.series_mates(0) == (2,) and inputs.series_mates(3) == (1,)
    np.testing.assert_allclose(inputs.pack_cutoff_v, 17.5)


@pytest.mark.parametrize("preset, full_v", [("plane-3s", 3 * 4.35), ("quad-4s", 16.8), ("quad-6s", 25.2), ("hex-6s", 25.2)])
def test_chemistry_default_is_scaled_to_the_pack(preset, full_v):
    desc = PRESETS[preset]
    inputs = model_inputs(desc)
    assert inputs.pack_matrix.shape == (len(desc.packs), kernel.N_PACK_PARAMS)
    x = kernel.initial_pack_state(inputs.pack_matrix, 1.0, 20.0)
    np.testing.assert_allclose(kernel.terminal_voltage(inputs.pack_matrix, x), full_v)
    np.testing.assert_allclose(inputs.pack_matrix[:, kernel.I_CMAX], desc.packs[0].capacity_mah * 3.6)
    # a 1C discharge to empty takes about an hour and ends near the knee, as the reference pack does
    cap_ah = desc.packs[0].capacity_mah / 1000
    run = kernel.simulate_packs(inputs.pack_matrix[:1], x[:1], np.full(3500, 1.0), np.full(3500, cap_ah), 20.0)
    assert 0.0 < run.soc[0, -1] < 0.05
    ref = kernel.simulate_packs(default_set().pack_matrix()[:1], kernel.initial_pack_state(default_set().pack_matrix()[:1], 1.0, 20.0),
                                np.full(3500, 1.0), np.full(3500, 7.8), 20.0)
    # per cell, the discharge curve is the reference pack's, moved to this pack's full voltage
    cells = desc.packs[0].cells_series
    np.testing.assert_allclose((run.voltage[0] - full_v) / cells, (ref.voltage[0] - 21.0) / 5, atol=2e-3)


def test_multirotor_power_momentum_theory():
    # hover: T v_h / FM with v_h = sqrt(T / (2 rho A))
    T = 1.6 * multirotor.G
    A = 4 * np.pi * 0.254 ** 2 / 4
    assert multirotor.hover_power(1.6, 4, 0.254, 0.65) == pytest.approx(T * np.sqrt(T / (2 * 1.225 * A)) / 0.65)
    p = multirotor.shaft_power(np.array([0.0, 8.0, 25.0]), 0.0, 1.6, 4, 0.254, 0.65, 0.015, 120.0)
    assert p[0] == pytest.approx(multirotor.hover_power(1.6, 4, 0.254, 0.65))
    assert p[1] < p[0] < p[2]   # the bucket: translational lift, then parasite drag
    climb = multirotor.shaft_power(0.0, 2.0, 1.6, 4, 0.254, 0.65, 0.015, 120.0)
    assert climb == pytest.approx(p[0] + T * 2.0)


def _battery(i, mv, remaining=100, consumed=0, temp=32767):
    return ("BATTERY_STATUS", {"id": i, "voltages": [mv] + [65535] * 9, "voltages_ext": [0] * 4,
                               "temperature": temp, "battery_remaining": remaining, "current_consumed": consumed})


def test_provisional_derivation_is_pure_over_messages():
    msgs = [("HEARTBEAT", {"type": 6, "autopilot": 8}),           # a GCS: not the vehicle
            ("HEARTBEAT", {"type": 13, "autopilot": 3}),          # hexarotor
            _battery(0, 25100), _battery(1, 24900, temp=2500),
            _battery(0, 23000, remaining=80, consumed=2000),
            ("ESC_TELEMETRY_1_TO_4", {"current": [100, 120, 0, 0], "rpm": [5000, 5100, 0, 0],
                                      "temperature": [0, 0, 0, 0], "voltage": [0] * 4, "count": [1, 1, 0, 0]}),
            ("ESC_TELEMETRY_5_TO_8", {"current": [90, 0, 0, 0], "rpm": [4900, 0, 0, 0],
                                      "temperature": [0] * 4, "voltage": [0] * 4, "count": [0] * 4})]
    # pack 1 has no capacity parameter and never discharged: its capacity is unknown, never guessed
    with pytest.raises(CapacityUnknown, match="pack battery1: capacity unknown: no BATT2_CAPACITY/BAT2_CAPACITY "
                                              "parameter seen, and battery_remaining has fallen 0 of the 10"):
        derive_provisional(msgs)
    desc, notes = derive_provisional(msgs, capacities={1: 8000.0})
    assert desc.provisional and desc.airframe.type == "multirotor"
    assert [(p.mavlink_battery_id, p.cells_series) for p in desc.packs] == [(0, 6), (1, 6)]
    assert desc.packs[0].capacity_mah == pytest.approx(10000)
    assert not desc.packs[0].reports_temperature and desc.packs[1].reports_temperature
    assert [m.esc_index for m in desc.motors] == [0, 1, 4]
    assert desc.motors[0].readings.current and not desc.motors[0].readings.temperature
    assert desc.feed_kind() == "packs in parallel"
    assert desc.packs[1].capacity_mah == 8000.0 and any("8000 mAh as given by the user" in n for n in notes)
    assert any("10000 mAh from the charge drawn" in n for n in notes)
    model_inputs(desc)                               # and it is a usable vehicle
    with pytest.raises(VehicleError, match="HEARTBEAT type 4"):
        derive_provisional([("HEARTBEAT", {"type": 4, "autopilot": 3}), _battery(0, 12000)])
    with pytest.raises(VehicleError, match="no BATTERY_STATUS"):
        derive_provisional([("HEARTBEAT", {"type": 1, "autopilot": 3})])


@needs_stock_tlog
def test_provisional_from_the_stock_arduplane_tlog():
    desc, _ = observe_tlog(STOCK_TLOG)
    assert desc.airframe.type == "fixed_wing"
    assert [(p.mavlink_battery_id, p.cells_series, p.reports_temperature) for p in desc.packs] == [(0, 3, False)]
    assert 3000 <= desc.packs[0].capacity_mah <= 3600    # SITL's BATT_CAPACITY is 3300 mAh
    assert [m.esc_index for m in desc.motors] == [2]
    assert desc.motors[0].readings.current and desc.motors[0].readings.rpm


@needs_stock_tlog
def test_cli_init_from_log_then_check_and_show(tmp_path, capsys):
    out = tmp_path / "mine.toml"
    assert main(["vehicle", "init", "--from", str(STOCK_TLOG), "--out", str(out)]) == 0
    assert main(["vehicle", "init", "--from", str(STOCK_TLOG), "--out", str(out)]) == 2   # no overwrite: an input error
    capsys.readouterr()
    assert main(["vehicle", "check", str(out)]) == 0
    assert "1 pack(s), 1 motor(s)" in capsys.readouterr().out
    assert main(["vehicle", "show", "quad-4s", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["name"] == "quad-4s"
    out.write_text(out.read_text().replace("esc_index = 2", "esc_index = -1"))
    assert main(["vehicle", "check", str(out)]) == 2
    assert "motors[0].esc_index" in capsys.readouterr().err
