"""Candidate agreement (gcs_pdm.fitting.agreement): which validation/test flights the training flights
do not determine, read from how far a fit's near-best candidates' predictions are apart."""
import json

import numpy as np
import pytest

from gcs_pdm.fitting.agreement import agreement_report, near_best


def test_near_best_keeps_the_candidates_validation_could_have_chosen_and_the_chosen_first():
    # training RMSE per candidate; the third is a poor minimum (3x the best)
    assert near_best([0.030, 0.040, 0.090, 0.044], starts=[0, 1, 2, 3], chosen=1) == [1, 0, 3]
    assert near_best([0.030, 0.040, 0.090, 0.044], starts=[0, 1, 2, 3], chosen=1, tolerance=1.2) == [1, 0]
    # a polished run (appended, same start as candidate 2) is chosen: its unpolished self is no second opinion
    assert near_best([0.030, 0.041, 0.033, 0.031], starts=[0, 1, 2, 2], chosen=3) == [3, 0, 1]
    # an LM run that failed (non-finite) is never a sibling; nothing finite leaves the chosen alone
    assert near_best([0.030, np.nan, 0.031], starts=[0, 1, 2], chosen=0) == [0, 2]
    assert near_best([np.nan, np.nan], starts=[0, 1], chosen=1) == [1]


def _flights(n=600):
    t = np.arange(n, dtype=np.float64)
    return t, 20.0 - 0.004 * t   # a pack sagging through a flight


def test_agreeing_candidates_determine_a_flight_and_parted_ones_do_not():
    _, v = _flights()
    flights = [("flight_a", "validation"), ("flight_b", "test")]
    # candidate 3 agrees on flight_a (5 mV apart) and parts on flight_b (120 mV apart); candidate 1 agrees on both
    voltages = {0: [v, v], 1: [v + 0.002, v - 0.004], 3: [v - 0.005, v + 0.120]}
    record, warnings = agreement_report(flights, voltages, chosen=0, chosen_train_rmse=0.030)
    assert record["measured"] and record["candidates"] == [0, 1, 3]
    assert record["threshold_v"] == pytest.approx(0.045)
    a, b = record["flights"]
    assert (a["flight"], a["split"], a["determined"]) == ("flight_a", "validation", True)
    assert a["spread_v"] == pytest.approx(0.005)
    assert (b["flight"], b["split"], b["determined"]) == ("flight_b", "test", False)
    assert b["spread_v"] == pytest.approx(0.120)
    assert len(warnings) == 1 and warnings[0].startswith("test flight flight_b: not determined by the training flights")
    assert "120 mV apart" in warnings[0] and "(30 mV)" in warnings[0]
    json.dumps(record, allow_nan=False)   # result.json is strict JSON


def test_the_threshold_scales_with_the_fits_own_training_error():
    _, v = _flights()
    voltages = {0: [v], 1: [v + 0.040]}
    record, warnings = agreement_report([("f", "test")], voltages, chosen=0, chosen_train_rmse=0.030)
    assert record["flights"][0]["determined"] is True and not warnings          # 40 mV < 1.5 x 30 mV
    record, warnings = agreement_report([("f", "test")], voltages, chosen=0, chosen_train_rmse=0.020)
    assert record["flights"][0]["determined"] is False and len(warnings) == 1   # 40 mV > 1.5 x 20 mV
    record, _ = agreement_report([("f", "test")], voltages, chosen=0, chosen_train_rmse=0.020, factor=2.5)
    assert record["flights"][0]["determined"] is True


def test_drop_outs_are_skipped_and_a_flight_with_no_common_sample_is_unknown():
    _, v = _flights()
    gap = v + 0.010
    gap[100:300] = np.nan
    record, _ = agreement_report([("gappy", "test")], {0: [v], 1: [gap]}, chosen=0, chosen_train_rmse=0.03)
    assert record["flights"][0]["spread_v"] == pytest.approx(0.010)
    blank = np.full_like(v, np.nan)
    record, warnings = agreement_report([("blank", "test")], {0: [v], 1: [blank]}, chosen=0, chosen_train_rmse=0.03)
    assert record["flights"][0] == {"flight": "blank", "split": "test", "spread_v": None, "determined": None}
    assert not warnings


def test_one_candidate_measures_nothing_and_says_so():
    _, v = _flights()
    record, warnings = agreement_report([("f", "validation"), ("g", "test")], {2: [v, v]}, chosen=2,
                                        chosen_train_rmse=0.03)
    assert record["measured"] is False and "no second fit" in record["reason"]
    assert [f["determined"] for f in record["flights"]] == [None, None] and not warnings
    json.dumps(record, allow_nan=False)
