"""Is a slow figure the code or the host? (issue 32; docs/notes/2026-11-27-extended-mc-5.md)

For ``--seconds`` (default 15), alternates the extended Monte Carlo that ``bench_estimate.py``
times (best of 3 calls) with the host's yardstick (``measure.host_yardstick_ms``), in one process
pinned to one CPU, with nothing allocated between rounds that the kernel keeps. If the two rise and
fall together, the slow figures are the host's phase, not the code or its memory layout.

Prints ONE JSON object: the number of rounds, the correlation of the two series, and each one's
median in the rounds whose yardstick is below / above ``--split_ms`` (default 1.6 ms, between the
~1.2 ms fast and ~2.0 ms slow phases of this host in Nov 2026).

Run: ``PYTHONPATH=$PWD python benchmarks/bench_host_phase.py [--seconds 15] [--split_ms 1.6]``
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_estimate import extended_monte_carlo  # noqa: E402
from measure import host_yardstick_ms, loadavg  # noqa: E402


def best_call_ms(call, n: int = 3) -> float:
    best = float("inf")
    for _ in range(n):
        c0 = time.process_time()
        call()
        best = min(best, time.process_time() - c0)
    return best * 1e3


def main() -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--split_ms", type=float, default=1.6)
    opts = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    call = extended_monte_carlo()
    call()
    host_yardstick_ms()
    figure, yardstick = [], []
    end = time.perf_counter() + opts.seconds
    while time.perf_counter() < end:
        figure.append(best_call_ms(call))
        yardstick.append(host_yardstick_ms())
    f, y = np.array(figure), np.array(yardstick)
    fast, slow = y < opts.split_ms, y >= opts.split_ms

    def medians(mask):
        if not mask.any():
            return {"rounds": 0, "figure_ms": "unknown (no round in this phase)", "yardstick_ms": "unknown"}
        return {"rounds": int(mask.sum()), "figure_ms": round(float(np.median(f[mask])), 2),
                "yardstick_ms": round(float(np.median(y[mask])), 2)}

    corr = float(np.corrcoef(f, y)[0, 1]) if f.size > 2 and f.std() > 0 and y.std() > 0 else None
    return {"benchmark": "bench_host_phase", "rounds": int(f.size),
            "correlation": round(corr, 2) if corr is not None else "unknown (fewer than 3 rounds or a constant series)",
            "fast_phase": medians(fast), "slow_phase": medians(slow), "loadavg_1min": loadavg()}


if __name__ == "__main__":
    print(json.dumps(main()))
