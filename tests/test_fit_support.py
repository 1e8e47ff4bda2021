"""How well the training flights' starts support each validation/test flight's initial SoC
(gcs_pdm.fitting.support, result.json's ``initial_soc_support`` and ``warnings``, the CLI's warning)."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.cli import main
from gcs_pdm.fitting.support import SOC_SUPPORT_SPAN, StartReading, initial_soc_support, support_report

ROOT = Path(__file__).resolve().parents[1] / "fixtures" / "pybamm"


def start(name, soc, split="train", voltage=None):
    # a 5S pack whose rest voltage rises 3 V per unit of SoC from 18 V: only the ordering matters here
    return StartReading(name, split, 18.0 + 3.0 * soc if voltage is None else voltage, 0.0, soc, 5)


TRAINING = [start("a", 0.60), start("b", 0.82), start("c", 0.88), start("d", 0.90), start("e", 0.99)]


def test_a_start_between_training_starts_far_apart_is_interpolated_with_its_neighbours_and_gap():
    r = initial_soc_support(start("t", 0.85, "test", voltage=20.40), TRAINING)
    assert r["support"] == "interpolated"
    assert r["nearest_below"]["flight"] == "b" and r["nearest_above"]["flight"] == "c"
    assert r["soc_gap"] == pytest.approx(0.06) and r["soc_to_nearest"] == pytest.approx(0.03)
    assert r["voltage_v"] == 20.40 and r["cell_voltage_v"] == pytest.approx(4.08)
    assert r["nearest_below"]["voltage_v"] == pytest.approx(18.0 + 3.0 * 0.82)
    assert "b (" in r["reason"] and "c (" in r["reason"] and "0.060-SoC span" in r["reason"]


def test_a_start_near_a_training_start_is_rested_even_in_a_wide_span():
    # 0.61 lies in the 0.22-wide span a-b, but 0.01 from a's start
    r = initial_soc_support(start("t", 0.61, "test"), TRAINING)
    assert r["support"] == "rested" and r["nearest_below"]["flight"] == "a" and "from the start of training flight a" in r["reason"]
    # the threshold is half the span on either side: just inside rested, just outside not
    half = SOC_SUPPORT_SPAN / 2
    assert initial_soc_support(start("t", 0.82 + half - 1e-6, "test"), TRAINING)["support"] == "rested"
    assert initial_soc_support(start("t", 0.82 + half + 1e-3, "test"), TRAINING)["support"] == "interpolated"
    # a narrower stated span turns the same start into an interpolated one
    assert initial_soc_support(start("t", 0.89, "test"), TRAINING)["support"] == "rested"
    assert initial_soc_support(start("t", 0.895, "test"), TRAINING, span=0.005)["support"] == "interpolated"


def test_a_start_beyond_the_training_starts_is_extrapolated_on_either_side():
    low = initial_soc_support(start("t", 0.50, "test"), TRAINING)
    assert low["support"] == "extrapolated" and low["nearest_below"] is None and low["nearest_above"]["flight"] == "a"
    assert low["soc_gap"] is None and "below the lowest" in low["reason"]
    high = initial_soc_support(start("t", 1.05, "test"), TRAINING)
    assert high["support"] == "extrapolated" and high["nearest_above"] is None and "above the highest" in high["reason"]
    # just beyond the outermost start, within the half span: still rested
    assert initial_soc_support(start("t", 1.0, "test"), TRAINING)["support"] == "rested"
    none = initial_soc_support(start("t", 0.9, "test"), [])
    assert none["support"] == "extrapolated" and "no training flight start" in none["reason"]


def test_a_bad_span_is_refused():
    with pytest.raises(ValueError, match="span"):
        initial_soc_support(start("t", 0.9, "test"), TRAINING, span=0.0)


def test_the_report_covers_validation_and_test_flights_and_warns_only_for_unsupported_ones():
    readings = TRAINING[::-1] + [start("v", 0.881, "validation"), start("t1", 0.85, "test"), start("t2", 0.3, "test")]
    record, warnings = support_report(readings)
    assert [r["flight"] for r in record["training_starts"]] == ["a", "b", "c", "d", "e"]  # in SoC order
    assert {f["flight"]: f["support"] for f in record["flights"]} == {"v": "rested", "t1": "interpolated",
                                                                       "t2": "extrapolated"}
    assert record["span"] == SOC_SUPPORT_SPAN
    assert len(warnings) == 2 and warnings[0].startswith("test flight t1: initial SoC interpolated")
    assert warnings[1].startswith("test flight t2: initial SoC extrapolated")


def test_cli_fit_reports_support_in_result_json_and_prints_the_warning(tmp_path, capsys):
    # training: chen2020_02 (rests at SoC ~0.99); validation: the same log under another name (the same
    # start, so rested at distance 0); test: chen2020_11 (rests ~0.9 V lower: below every training start)
    train = ROOT / "Chen2020" / "chen2020_02.parquet"
    val = shutil.copy(train, tmp_path / "again_02.parquet")
    test = ROOT / "Chen2020" / "chen2020_11.parquet"
    budget = ["--starts", "2", "--sa-generations", "4", "--lm-max-nfev", "4", "--quiet", "--no-plots"]
    rc = main(["fit", "battery", "--train", str(train), "--val", str(val), "--test", str(test),
               "--out", str(tmp_path / "out"), *budget])
    assert rc == 0
    captured = capsys.readouterr()
    d = json.loads((tmp_path / "out" / "result.json").read_text())
    sup = d["initial_soc_support"]
    assert [t["flight"] for t in sup["training_starts"]] == ["chen2020_02"]
    flights = {f["flight"]: f for f in sup["flights"]}
    assert set(flights) == {"again_02", "chen2020_11"}
    again, low = flights["again_02"], flights["chen2020_11"]
    assert again["support"] == "rested" and again["soc_to_nearest"] == 0.0
    assert low["support"] == "extrapolated" and low["nearest_above"]["flight"] == "chen2020_02"
    assert low["nearest_below"] is None and low["soc"] < sup["training_starts"][0]["soc"] - SOC_SUPPORT_SPAN / 2
    # the start is the flight's leading rest: 5 cells, the first samples' mean, the SoC the fit predicts from
    import pandas as pd

    lead = pd.read_parquet(test)["voltage_v"].iloc[:10].mean()
    assert low["voltage_v"] == pytest.approx(lead, abs=0.02) and low["cell_voltage_v"] == pytest.approx(low["voltage_v"] / 5)
    assert low["soc"] == d["initial_soc"]["chen2020_11"] and abs(low["current_a"]) < 0.2
    start_warnings = [w for w in d["warnings"] if "initial SoC" in w]
    assert len(start_warnings) == 1 and "chen2020_11" in start_warnings[0]
    # chen2020_11 also flies hotter and harder than the one training flight (6.8 C air, 1C): said too
    envelope = {f["flight"]: f for f in d["operating_envelope"]["flights"]}
    assert envelope["again_02"]["inside"] and not envelope["chen2020_11"]["inside"]
    assert any(r.startswith("pack temperature reaches 44.") for r in envelope["chen2020_11"]["outside"])
    assert [w for w in d["warnings"] if "outside the training conditions" in w] == [
        w for w in d["warnings"] if w.startswith("test flight chen2020_11: outside")]
    assert "fit: warning: LLF20: test flight chen2020_11: initial SoC extrapolated" in captured.err
    summary = json.loads(captured.out.splitlines()[0])
    assert summary["initial_soc_support"] == {"again_02": "rested", "chen2020_11": "extrapolated"}
    assert summary["outside_training_conditions"] == ["chen2020_11"]
    assert summary["left_out_training_flights"] == [] and d["left_out"] == []   # one training flight: nothing to judge
    assert "fit: warning: LLF20: test flight chen2020_11: outside the training conditions" in captured.err
    # candidate agreement: in result.json, and in the summary as a list, or null when nothing was compared
    agreement = d["candidate_agreement"]
    assert {f["flight"] for f in agreement["flights"]} == {"again_02", "chen2020_11"}
    undetermined = [f["flight"] for f in agreement["flights"] if f["determined"] is False]
    assert summary["undetermined_flights"] == (undetermined if agreement["measured"] else None)
    for name in undetermined:
        assert f"fit: warning: LLF20: {next(f['split'] for f in agreement['flights'] if f['flight'] == name)} " \
               f"flight {name}: not determined" in captured.err
    assert np.isfinite(low["soc"])
