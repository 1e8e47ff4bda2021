"""The reliability bench's bookkeeping (benchmarks/bench_failure_reliability.py): which bin a
predicted P(failure) falls in, the binomial interval and the figure at P <= ε. Pure numpy/scipy: no
flight is flown here."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_failure_reliability.py"
spec = importlib.util.spec_from_file_location("bench_failure_reliability", SCRIPT)
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def test_bins_hold_their_upper_edge_and_the_first_holds_epsilon():
    predicted = np.array([0.0, 0.02, 0.0201, 0.1, 0.5, 0.95, 1.0])
    failed = np.array([False, True, False, True, True, False, True])
    rows = {tuple(r["bin"]): r for r in bench.reliability(predicted, failed)}
    assert rows[(0.0, 0.02)]["count"] == 2 and rows[(0.0, 0.02)]["observed"] == 0.5
    assert rows[(0.02, 0.1)]["count"] == 2 and rows[(0.02, 0.1)]["mean_predicted"] == pytest.approx(0.06005, abs=1e-4)
    assert rows[(0.3, 0.5)]["count"] == 1
    assert rows[(0.9, 1.0)]["count"] == 2 and rows[(0.9, 1.0)]["observed"] == 0.5
    assert sum(r["count"] for r in rows.values()) == predicted.size  # empty bins left out, none lost


def test_clopper_pearson_matches_the_closed_forms():
    # no failure in n: the upper bound solves (1 - p)^n = 0.05; all failed: the lower solves p^n = 0.05
    assert bench.clopper_pearson(0, 100) == (0.0, pytest.approx(1 - 0.05 ** (1 / 100)))
    assert bench.clopper_pearson(100, 100) == (pytest.approx(0.05 ** (1 / 100)), 1.0)
    lo, hi = bench.clopper_pearson(10, 100)
    assert lo < 0.1 < hi and hi - lo < 0.12
    with pytest.raises(ValueError):
        bench.clopper_pearson(0, 0)


def test_bad_predictions_are_refused():
    with pytest.raises(ValueError, match="outside"):
        bench.reliability(np.array([1.2]), np.array([True]))
    with pytest.raises(ValueError, match="outcomes"):
        bench.reliability(np.array([0.1, 0.2]), np.array([True]))


def test_summary_counts_the_pairs_given_p_at_most_epsilon():
    predicted = np.array([0.0] * 50 + [0.02] * 50 + [0.5] * 10)
    failed = np.zeros(110, dtype=bool)
    failed[[3, 60]] = True
    failed[100:105] = True
    s = bench.summary(predicted, failed, 0.02)
    assert s["given_p_le_epsilon"]["pairs"] == 100 and s["given_p_le_epsilon"]["observed"] == 0.02
    assert s["given_0_lt_p_le_epsilon"]["pairs"] == 50 and s["given_0_lt_p_le_epsilon"]["observed"] == 0.02
    # a perfect forecaster scores 0; here the P = 0 and 0.02 pairs that failed and the coin-flips cost
    assert s["brier"] == pytest.approx(np.mean((predicted - failed) ** 2), abs=1e-4)
    none = bench.summary(np.array([0.5]), np.array([True]), 0.02)["given_p_le_epsilon"]
    assert none["observed"] is None and "no route" in none["why"]
