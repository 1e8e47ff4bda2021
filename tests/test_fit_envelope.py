"""The operating envelope a battery fit reports (gcs_pdm.models.training_envelope): which validation and test
flights leave the training flights' temperatures and currents, where the learned circuit extrapolates."""
import json

import numpy as np
import pytest

from gcs_pdm.models.training_envelope import (CURRENT_MARGIN_REL, SUSTAINED_S, TEMPERATURE_MARGIN_K, FlightConditions,
                                      envelope_report, sustained_current)


def flight(name, split, t_pack=(20.0, 40.0), ambient=20.0, current=10.0, n=600, spike=None):
    temps = np.linspace(*t_pack, n)
    cur = np.full(n, current)
    if spike is not None:
        cur[n // 2] = spike
    return FlightConditions.of(name, split, temps, np.full(n, ambient), cur, np.arange(n, dtype=float))


TRAIN = [flight("a", "train", (5.0, 30.0), 5.0, 8.0), flight("b", "train", (25.0, 55.0), 25.0, 15.0),
         flight("c", "train", (10.0, 35.0), 10.0, 12.0)]


def report(*flights):
    return envelope_report(TRAIN + list(flights))


def test_a_flight_inside_the_training_conditions_is_inside_and_not_warned():
    record, warnings = report(flight("v", "validation", (12.0, 50.0), 15.0, 14.0))
    assert record["training"] == {"pack_temperature_c": [5.0, 55.0], "ambient_c": [5.0, 25.0], "sustained_current_a": 15.0}
    (v,) = record["flights"]
    assert v["inside"] and v["outside"] == [] and warnings == []


def test_hotter_colder_and_harder_flights_are_outside_with_each_reason():
    hot = flight("hot", "test", (30.0, 55.0 + TEMPERATURE_MARGIN_K + 1.0), 24.0, 14.0)
    cold_air = flight("cold", "test", (5.0, 20.0), 5.0 - TEMPERATURE_MARGIN_K - 1.0, 10.0)
    hard = flight("hard", "validation", (20.0, 40.0), 20.0, 15.0 * (1 + CURRENT_MARGIN_REL) + 0.5)
    record, warnings = report(hot, cold_air, hard)
    by = {f["flight"]: f for f in record["flights"]}
    assert by["hot"]["outside"] == ["pack temperature reaches 58.0 °C, above the training flights' 55.0 °C"]
    assert by["cold"]["outside"] == ["air temperature goes down to 2.0 °C, below the training flights' 5.0 °C"]
    assert by["hard"]["outside"] == ["sustained current reaches 17.0 A, above the training flights' 15.0 A"]
    assert [w.split(":")[0] for w in warnings] == ["test flight hot", "test flight cold", "validation flight hard"]
    assert all("its prediction extrapolates the learned circuit" in w for w in warnings)


def test_within_the_margins_is_inside():
    near = flight("near", "test", (5.0 - TEMPERATURE_MARGIN_K + 0.1, 55.0 + TEMPERATURE_MARGIN_K - 0.1), 24.0,
                  15.0 * (1 + CURRENT_MARGIN_REL) - 0.1)
    record, warnings = report(near)
    assert record["flights"][0]["inside"] and not warnings


def test_a_current_spike_is_not_a_sustained_current():
    spiky = flight("spiky", "test", current=10.0, spike=200.0)
    record, _ = report(spiky)
    assert record["flights"][0]["inside"]
    # 1 Hz: the spike's sample adds (200 - 10) A over two half-seconds to one minute's charge
    assert record["flights"][0]["sustained_current_a"] == pytest.approx((10.0 * SUSTAINED_S + 190.0) / SUSTAINED_S)


def test_sustained_means_seconds_whatever_the_logs_rate():
    # a 2-minute climb at 30 A inside a 10-minute cruise at 10 A, logged at 1 Hz and at 10 Hz (and
    # with a gap): the highest one-minute mean is the climb's either way
    for hz in (1.0, 10.0):
        t = np.arange(0.0, 600.0, 1.0 / hz)
        i = np.where((t >= 200.0) & (t < 320.0), 30.0, 10.0)
        assert sustained_current(t, i) == pytest.approx(30.0, abs=0.2)
        keep = (t < 400.0) | (t > 450.0)
        assert sustained_current(t[keep], i[keep]) == pytest.approx(30.0, abs=0.2)
    # a burst shorter than the window is averaged with what is around it
    t = np.arange(0.0, 600.0)
    assert sustained_current(t, np.where((t >= 200) & (t < 230), 30.0, 10.0)) == pytest.approx(20.0, abs=0.4)
    # a log shorter than the window: its mean; nothing finite: None
    assert sustained_current(np.arange(30.0), np.full(30, 7.0)) == pytest.approx(7.0)
    assert sustained_current(np.arange(3.0), np.full(3, np.nan)) is None


def test_missing_temperatures_are_not_judged_and_the_record_is_json():
    no_sensor = FlightConditions.of("blind", "test", np.full(300, np.nan), np.full(300, 20.0), np.full(300, 9.0),
                                    np.arange(300.0))
    record, warnings = report(no_sensor)
    (f,) = record["flights"]
    assert f["pack_temperature_c"] is None and f["inside"] and not warnings
    json.dumps(record, allow_nan=False)


def test_training_flights_are_not_judged_and_no_training_flight_judges_nothing():
    record, _ = report()
    assert record["flights"] == []
    record, warnings = envelope_report([flight("t", "test", (80.0, 90.0))])
    assert record["training"]["pack_temperature_c"] is None and record["flights"][0]["inside"] and not warnings
