"""The try-out of docs/operations.md with the operator's approval 100 s late (issue 31, part 4).

``run_demo`` under the policy ``advise`` at the try-out's speed-up (x20; the service re-evaluates a
proposal every 60 s of flight at that speed), its clock NOT held for the operator, who approves the
first proposal only once it is ``--late`` seconds old in the vehicle's time. Checked, per seed:

* that approval is refused as stale (409) and what is uploaded is a plan made after it: the
  re-evaluated one, not the late-approved proposal;
* the vehicle lands, and its TRUE lowest pack lands inside the p05–p95 the last uploaded plan showed;
* the landing-forecast alarm: whether a replan was triggered by it (the browser test
  tests/browser/test_console_alarm.py checks the banner itself).

    python benchmarks/bench_tryout_late_approval.py [--seeds 1] [--late 100]

Prints one line per seed, then the figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs_pdm.service.demo import run_demo, uploaded_promise  # noqa: E402


def one_seed(seed: int, late_s: float, speedup: float) -> dict:
    t0 = time.perf_counter()
    lines: list[str] = []
    with tempfile.TemporaryDirectory(prefix="bench-tryout-") as data_dir:
        r = run_demo(speedup=speedup, http_port=0, data_dir=data_dir, seed=seed, timeout_s=900.0, out=lines.append,
                     compare=False, policy="advise", hold_while_deciding=False, approve_late_s=late_s)
    history = r.http.get("/missions/history", [])
    promise = uploaded_promise(history, r.http.get("/missions/uploads", []))
    first = r.operator_answers[0] if r.operator_answers else None
    late_plan = next((p for p in history if first and p["id"] == first[0]), None)
    truth = min(r.landing_soc) if r.landing_soc else None
    row = {"seed": seed, "landed": r.landed, "failed": r.failure if r.failed else None, "reached": r.reached,
           "operator_answers": r.operator_answers, "late_plan_status": late_plan and late_plan["status"],
           "promise": promise, "true_landing_soc_lowest": truth,
           "alarm_replans": sum(1 for p in history if str(p.get("trigger", "")).startswith("alarm:")),
           "wall_s": time.perf_counter() - t0}
    if first is not None and promise is not None:
        row["late_approval_refused"] = first[2] == 409
        row["uploaded_is_reevaluated"] = bool(promise["plan_id"] != first[0] and late_plan is not None
                                              and promise["time_s"] > late_plan["time_s"])
    if promise is not None and truth is not None:
        lo, _, hi = promise["landing_soc_p05_p50_p95"]
        row["inside_p05_p95"] = bool(r.landed and lo <= truth <= hi)
    return row


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--late", type=float, default=100.0)
    ap.add_argument("--speedup", type=float, default=20.0)
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        row = one_seed(seed, args.late, args.speedup)
        rows.append(row)
        p, truth = row["promise"], row["true_landing_soc_lowest"]
        print(f"seed {seed}: approvals {row['operator_answers']} (late plan now {row['late_plan_status']}), "
              f"uploaded plan {p and p['plan_id']} re-evaluated {row.get('uploaded_is_reevaluated')}, "
              f"{'landed' if row['landed'] else 'NOT landed'}, truth "
              f"{'-' if truth is None else f'{100 * truth:.1f} %'} in "
              f"{'-' if not p else '%.1f–%.1f %%' % (100 * p['landing_soc_p05_p50_p95'][0], 100 * p['landing_soc_p05_p50_p95'][2])}"
              f" -> {row.get('inside_p05_p95')}; alarm replans {row['alarm_replans']}", flush=True)
    print(json.dumps({"late_s": args.late, "speedup": args.speedup, "seeds": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
