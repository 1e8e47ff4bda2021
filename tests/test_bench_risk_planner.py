"""The risk planner bench's "Done when" bookkeeping (benchmarks/bench_risk_planner.py ``done_when``):
the failure bound and the reward kept where the deterministic plan is also safe. No flight is flown."""
import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_risk_planner.py"
spec = importlib.util.spec_from_file_location("bench_risk_planner", SCRIPT)
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def _row(reward: float, failures: int = 0, truths: int = 200, feasible: bool = True) -> dict:
    return {"mean_reward": reward, "failures": failures, "truths": truths, "feasible_by_verdict": feasible,
            "failure_rate_upper95": bench.wilson_upper(failures, truths)}


def test_wilson_upper_bound_of_no_failure_in_200_is_about_1_9_percent():
    assert bench.wilson_upper(0, 200) == pytest.approx(0.0188, abs=1e-4)
    assert bench.wilson_upper(0, 0) == 1.0
    assert bench.wilson_upper(10, 100) > 0.1


def test_reward_ratio_counts_only_scenarios_where_the_deterministic_plan_is_safe():
    table = {
        "safe": {"pf_deterministic": _row(200.0), "pf_risk": _row(196.0), "exact_risk": _row(200.0)},
        # the deterministic plan keeps every truth in the air but misses the reserve quantile
        "reserve_missed": {"pf_deterministic": _row(100.0, feasible=False), "pf_risk": _row(180.0),
                           "exact_risk": _row(180.0)},
        # the deterministic plan loses truths: not a scenario the reward is compared on
        "lossy": {"pf_deterministic": _row(300.0, failures=30, feasible=False), "pf_risk": _row(100.0),
                  "exact_risk": _row(100.0)},
    }
    out = bench.done_when(table, eps=0.02)
    no_loss = out["reward_vs_deterministic"]["no_loss"]
    assert set(no_loss["ratios"]) == {"safe", "reserve_missed"}
    assert no_loss["min_ratio"] == pytest.approx(0.98) and no_loss["met"]
    quantile = out["reward_vs_deterministic"]["reserve_quantile"]
    assert set(quantile["ratios"]) == {"safe"} and quantile["met"]
    # the risk PF keeping 94 % where the deterministic plan is safe does not meet the bullet
    table["safe"]["pf_risk"] = _row(188.0)
    assert not bench.done_when(table, eps=0.02)["reward_vs_deterministic"]["reserve_quantile"]["met"]


def test_failure_bound_is_judged_on_every_risk_bounded_plan():
    table = {"a": {"pf_deterministic": _row(1.0, failures=50), "pf_risk": _row(1.0), "exact_risk": _row(1.0)}}
    out = bench.done_when(table, eps=0.02)["failure_bound"]
    # the deterministic plan's losses are not the risk planner's
    assert out["met"] and out["pooled_failures"] == 0 and out["pooled_truths"] == 400
    table["a"]["exact_risk"] = _row(1.0, failures=4)  # 2 % lost: its 95 % upper bound is above 3 %
    out = bench.done_when(table, eps=0.02)["failure_bound"]
    assert not out["met"] and out["worst_upper95"] > 0.03 and out["pooled_failures"] == 4
