"""Does the demo's promise hold on the vehicle? (issue 31, "the demo").

``gcs-pdm demo`` (the policy ``auto``, the vehicle's clock held while the service decides) for each
``--seeds``: the last confirmed upload's plan shows the lowest pack's landing SoC as p05–p95 over
the risk draws ("gets home with X % (p05–p95)"); the simulated vehicle's TRUE packs are read
where it ends. Reported per seed: the interval, the truth's lowest pack, whether the interval holds
it, and whether the truth kept the landing reserve.

    python benchmarks/bench_demo_landing.py [--seeds 1 2 3]

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


def one_seed(seed: int) -> dict:
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-demo-") as data_dir:
        r = run_demo(speedup=60.0, http_port=0, data_dir=data_dir, seed=seed, timeout_s=600.0, out=lambda _: None,
                     compare=False, hold_while_deciding=True)
    promise = uploaded_promise(r.http.get("/missions/history", []), r.http.get("/missions/uploads", []))
    truth = min(r.landing_soc) if r.landing_soc else None
    row = {"seed": seed, "landed": r.landed, "failed": r.failed, "failure": r.failure, "reached": r.reached,
           "uploads": r.uploads, "true_landing_soc_lowest": truth, "true_landing_soc": r.landing_soc,
           "promise": promise, "wall_s": time.perf_counter() - t0}
    if promise is not None and truth is not None:
        lo, _, hi = promise["landing_soc_p05_p50_p95"]
        row["inside_p05_p95"] = bool(lo <= truth <= hi)
        row["reserve_kept"] = bool(r.landed and truth >= promise["reserve_soc"])
    return row


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        row = one_seed(seed)
        rows.append(row)
        p = row["promise"]
        shown = (f"plan {p['plan_id']} at t={p['time_s']:.0f} s promised {100 * p['landing_soc_p05_p50_p95'][0]:.1f}–"
                 f"{100 * p['landing_soc_p05_p50_p95'][2]:.1f} %" if p else "no risk-bounded upload")
        truth = row["true_landing_soc_lowest"]
        print(f"seed {seed}: {'landed' if row['landed'] else 'NOT landed: ' + str(row['failure'])}, {shown}, "
              f"truth {100 * truth:.1f} % -> inside {row.get('inside_p05_p95')}, reserve kept {row.get('reserve_kept')}"
              if truth is not None else f"seed {seed}: no truth", flush=True)
    print(json.dumps({"seeds": rows, "all_inside": all(r.get("inside_p05_p95") for r in rows),
                      "all_reserve_kept": all(r.get("reserve_kept") for r in rows)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
