"""The test suite's wall time under xdist, and where it goes: the warm-up and collection before the
first test, each worker's busy time, the idle tail (one worker done, the other still running), the
slowest tests (docs/notes/2026-11-27-test-time.md).

    python benchmarks/bench_test_suite.py [-n 2] [-- PYTEST ARGUMENTS]
    python benchmarks/bench_test_suite.py --timeline run.jsonl     # summarise a recorded run

Runs ``pytest -q -n N -p no:cacheprovider`` from the repository with a small plugin (this file) that
appends one line per test (worker, node id, start, end) to a timeline file. Measure at low load
(``uptime``), or say the load: the durations of a loaded machine are relative only. Prints the
figures as ONE JSON object on the last line.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TIMELINE_ENV = "GCS_PDM_TEST_TIMELINE"


_outcomes: dict[str, str] = {}


def pytest_runtest_logreport(report):  # the plugin side (-p bench_test_suite): the worst phase's outcome
    if report.failed:
        _outcomes[report.nodeid] = "failed" if report.when == "call" else "error"
    elif report.skipped or report.when == "call":
        _outcomes.setdefault(report.nodeid, report.outcome)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    start = time.time()
    yield
    path = os.environ.get(TIMELINE_ENV)
    if path:
        row = {"worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), "nodeid": item.nodeid,
               "start": start, "end": time.time(), "outcome": _outcomes.pop(item.nodeid, "passed")}
        with open(path, "a") as f:  # one short line per write: the workers' lines do not interleave
            f.write(json.dumps(row) + "\n")


def summarise(rows: list[dict], started: float | None = None, ended: float | None = None,
              slowest: int = 20) -> dict:
    """Figures of one run from its timeline rows (``started``/``ended``: the command's wall clock)."""
    if not rows:
        raise ValueError("the timeline holds no test: did pytest run any?")
    first = min(r["start"] for r in rows)
    last = max(r["end"] for r in rows)
    t0 = started if started is not None else first
    workers = {}
    for w in sorted({r["worker"] for r in rows}):
        mine = [r for r in rows if r["worker"] == w]
        workers[w] = {"tests": len(mine), "busy_s": round(sum(r["end"] - r["start"] for r in mine), 1),
                      "done_at_s": round(max(r["end"] for r in mine) - t0, 1)}
    done = sorted(v["done_at_s"] for v in workers.values())
    by_time = sorted(rows, key=lambda r: r["end"] - r["start"], reverse=True)[:slowest]
    return {
        "wall_s": round((ended if ended is not None else last) - t0, 1),
        "first_test_at_s": round(first - t0, 1),  # warm-up, start of the workers, collection
        "tests": len(rows),
        "sum_of_tests_s": round(sum(r["end"] - r["start"] for r in rows), 1),
        "workers": workers,
        "idle_tail_s": round(done[-1] - done[0], 1),
        "not_passed": sorted(f"{r['nodeid']}: {r['outcome']}" for r in rows if r.get("outcome", "passed") != "passed"),
        "slowest": [{"s": round(r["end"] - r["start"], 1), "worker": r["worker"],
                     "started_at_s": round(r["start"] - t0, 1), "test": r["nodeid"]} for r in by_time],
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", default="2", help="xdist workers (default 2, the CI machine's cores)")
    ap.add_argument("--timeline", type=Path, help="summarise this recorded timeline instead of running")
    ap.add_argument("--started", type=float, help="with --timeline: the run's start (Unix time; default its first test)")
    ap.add_argument("--ended", type=float, help="with --timeline: the run's end (Unix time; default its last test)")
    ap.add_argument("pytest_args", nargs="*", help="after --: passed to pytest")
    args = ap.parse_args(argv)
    if args.timeline:
        rows = [json.loads(line) for line in args.timeline.read_text().splitlines() if line.strip()]
        print(json.dumps(summarise(rows, args.started, args.ended)))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        timeline = Path(tmp) / "timeline.jsonl"
        env = dict(os.environ, **{TIMELINE_ENV: str(timeline)})
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "benchmarks"), env.get("PYTHONPATH", "")])
        load_before = os.getloadavg()
        started = time.time()
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", args.n, "-p", "no:cacheprovider",
                               "-p", "bench_test_suite", *args.pytest_args], cwd=REPO, env=env)
        ended = time.time()
        rows = [json.loads(line) for line in timeline.read_text().splitlines()] if timeline.exists() else []
    out = summarise(rows, started, ended)
    out.update(pytest_exit=proc.returncode, load_before=[round(x, 2) for x in load_before],
               load_after=[round(x, 2) for x in os.getloadavg()])
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
