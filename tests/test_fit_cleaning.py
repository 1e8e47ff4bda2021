"""Cleaning of flight logs: one test per kind of damage, and clear errors for bad input."""
import numpy as np
import pytest

from gcs_pdm.fitting.cleaning import CleaningSettings, clean_flight
from gcs_pdm.fitting.logs import read_flights, read_table, write_table
from gcs_pdm.logs.tables import BATTERY, MOTOR, Flight, FlightDataError, flight_from_columns
from gcs_pdm.vehicle.presets import PRESETS

EDGE540 = PRESETS["edge540"]  # a table holds one pack: the vehicle names no column


def _flight(n=600, seed=0, **over):
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    cur = 10.0 + 2.0 * np.sin(t / 50.0)
    cols = dict(time_s=t, current_a=cur, voltage_v=20.5 - 0.001 * t - 0.04 * cur + rng.normal(0, 0.02, n),
                temperature_c=25.0 + 0.005 * t + rng.normal(0, 0.2, n), ambient_c=15.0 + rng.normal(0, 0.1, n))
    cols.update(over)
    return Flight(name="f", kind=BATTERY, **cols)


def test_clean_flight_passes_good_data_unchanged():
    f = _flight()
    r = clean_flight(f)
    assert r.rejected is None and len(r.flights) == 1
    g = r.flights[0]
    np.testing.assert_array_equal(g.voltage_v, f.voltage_v)
    assert sum(v for k, v in r.report.counts.items()) == 0


def test_backwards_and_duplicated_timestamps_are_sorted_and_deduplicated():
    f = _flight()
    idx = np.arange(len(f))
    idx[[100, 101]] = idx[[101, 100]]             # one pair swapped -> one step backwards
    idx = np.insert(idx, 200, 200)                # a repeated row
    g = f.take(idx)
    r = clean_flight(g)
    out = r.flights[0]
    assert np.all(np.diff(out.time_s) > 0)
    assert len(out) == len(f)
    assert r.report.counts["backwards_timestamps"] == 1
    assert r.report.counts["duplicate_timestamps"] == 1
    np.testing.assert_array_equal(out.voltage_v, f.voltage_v)


def test_spikes_are_removed_and_steps_are_kept():
    f = _flight()
    v = f.voltage_v.copy()
    v[300] += 5.0
    v[400:] -= 1.0  # a genuine step (load change) must stay
    r = clean_flight(f.with_columns(voltage_v=v))
    out = r.flights[0]
    assert r.report.counts["spikes_voltage_v"] == 1
    assert np.isnan(out.voltage_v[300])
    assert np.isfinite(out.voltage_v[398:404]).all()


def test_stuck_sensor_run_becomes_missing():
    f = _flight()
    temp = f.temperature_c.copy()
    temp[100:140] = temp[100]
    temp[120] = np.nan  # a drop-out inside the stuck run does not hide it
    r = clean_flight(f.with_columns(temperature_c=temp))
    assert r.report.counts["stuck_runs_temperature_c"] == 1
    assert r.report.counts["stuck_samples_temperature_c"] == 39
    assert np.isnan(r.flights[0].temperature_c[100:140]).all()


def test_sign_flips_whole_log_and_samples():
    f = _flight()
    r = clean_flight(f.with_columns(current_a=-f.current_a))
    assert r.report.counts["current_sign_flipped_log"] == 1
    np.testing.assert_allclose(r.flights[0].current_a, f.current_a)
    cur = f.current_a.copy()
    cur[250:260] *= -1
    r = clean_flight(f.with_columns(current_a=cur))
    assert r.report.counts["current_sign_flipped_samples"] == 10
    np.testing.assert_allclose(r.flights[0].current_a, f.current_a)


def test_unit_mistakes_millivolts_and_kelvin():
    f = _flight()
    r = clean_flight(f.with_columns(voltage_v=f.voltage_v * 1000.0, ambient_c=f.ambient_c + 273.15))
    assert r.report.counts["voltage_mv_to_v"] == 1
    assert r.report.counts["ambient_c_kelvin_to_c"] == 1
    np.testing.assert_allclose(r.flights[0].voltage_v, f.voltage_v)
    np.testing.assert_allclose(r.flights[0].ambient_c, f.ambient_c)


def test_dropouts_inputs_interpolated_outputs_left_missing():
    f = _flight()
    cur, v = f.current_a.copy(), f.voltage_v.copy()
    cur[50] = np.nan
    v[60] = np.nan
    r = clean_flight(f.with_columns(current_a=cur, voltage_v=v))
    out = r.flights[0]
    assert r.report.counts["interpolated_current_a"] == 1
    assert out.current_a[50] == pytest.approx(0.5 * (f.current_a[49] + f.current_a[51]))
    assert np.isnan(out.voltage_v[60]) and r.report.counts["missing_voltage_v"] == 1


def test_out_of_range_values_become_missing():
    f = _flight()
    temp = f.temperature_c.copy()
    temp[10] = 900.0
    r = clean_flight(f.with_columns(temperature_c=temp))
    assert r.report.counts["out_of_range_temperature_c"] == 1
    assert np.isnan(r.flights[0].temperature_c[10])


def test_short_gap_bridged_long_gap_splits():
    f = _flight(n=1000)
    keep = np.ones(1000, bool)
    keep[100:110] = False       # 11 s step: bridged
    keep[500:600] = False       # 101 s: split
    r = clean_flight(f.take(keep), CleaningSettings(min_duration_s=200.0))
    assert r.report.counts["split_gaps"] == 1
    assert r.report.counts["bridged_gaps"] == 1
    assert [g.name for g in r.flights] == ["f#1", "f#2"]
    assert r.flights[0].time_s[-1] == 499 and r.flights[1].time_s[0] == 600


def test_short_segment_dropped_and_counted():
    f = _flight(n=1000)
    keep = np.ones(1000, bool)
    keep[850:900] = False
    r = clean_flight(f.take(keep), CleaningSettings(min_duration_s=200.0))
    assert len(r.flights) == 1 and r.report.counts["short_segments_dropped"] == 1


def test_too_damaged_flight_is_rejected_with_reason():
    f = _flight()
    v = f.voltage_v.copy()
    v[::2] = np.nan
    r = clean_flight(f.with_columns(voltage_v=v))
    assert r.flights == [] and r.rejected is not None
    assert "voltage_v missing" in r.rejected.reason
    r = clean_flight(_flight(n=20))
    assert "rows" in r.rejected.reason


def test_missing_column_is_a_clear_error(tmp_path):
    with pytest.raises(FlightDataError, match="missing required column.*voltage_v"):
        flight_from_columns("x", BATTERY, {"time_s": [0, 1], "current_a": [1, 1], "temperature_c": [1, 1],
                                           "ambient_c": [1, 1]})
    p = tmp_path / "bad.csv"
    p.write_text("time_s,current_a,temperature_c\n0,1,2\n")
    with pytest.raises(FlightDataError, match="bad: missing required column.*ambient_c"):
        read_table(p, MOTOR)


def test_bad_files_give_clear_errors(tmp_path):
    with pytest.raises(FlightDataError, match="no such file"):
        read_flights(tmp_path / "nope.csv", BATTERY, vehicle=EDGE540)
    p = tmp_path / "x.txt"
    p.write_text("hello")
    with pytest.raises(FlightDataError, match="unknown flight file type"):
        read_flights(p, BATTERY, vehicle=EDGE540)
    p = tmp_path / "garbage.parquet"
    p.write_bytes(b"\x00\x01not parquet")
    with pytest.raises(FlightDataError, match="cannot read table"):
        read_flights(p, BATTERY, vehicle=EDGE540)
    p = tmp_path / "text.csv"
    p.write_text("time_s,current_a,voltage_v,temperature_c,ambient_c\n0,a,b,c,d\n")
    with pytest.raises(FlightDataError, match="not numeric"):
        read_flights(p, BATTERY, vehicle=EDGE540)


def test_table_round_trip_extra_columns_ignored(tmp_path):
    f = _flight()
    for suffix in (".csv", ".parquet"):
        p = write_table(f, tmp_path / f"a{suffix}")
        g = read_flights(p, BATTERY, vehicle=EDGE540)[0]
        np.testing.assert_allclose(g.voltage_v, f.voltage_v)
    import pandas as pd
    df = pd.read_csv(tmp_path / "a.csv").assign(rpm=1.0)
    df.to_csv(tmp_path / "b.csv", index=False)
    assert read_flights(tmp_path / "b.csv", BATTERY, vehicle=EDGE540)[0].name == "b"
