"""A newcomer's first run (issue 33): ``gcs-pdm replay`` of a 650-s tlog from a cold numba cache,
the same replay once cached, and the demo's preparation of its compiled paths from a cold cache.

    PYTHONPATH=$PWD python benchmarks/bench_first_run.py [TLOG]

"Cold" is a fresh, empty ``NUMBA_CACHE_DIR`` per measurement (nothing compiled, as after a fresh
clone); each figure is one child process (start-up included): wall and CPU seconds (the child's and
its own children's: the compile workers) and the load average, since on a shared machine the wall
time measures the neighbours too.

The cold replay runs interpreted while its models compile in a detached background process
(``compiled.interpret_while_cold``): its CPU is the foreground's only. ``background_compile_wall_s``
is how long after the cold replay that compilation held its lock; the cached replay starts once it
is done. ``same_summary``: the cold and the cached replay print the same summary (timings aside).
For the demo, the CPU time spread over the cores is the wall time an idle machine would take at
best (``wall_idle_bound_s``). Prints a line per figure and, last, one JSON object.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(REPO))
from measure import timed_process  # noqa: E402

DEFAULT_TLOG = REPO / "fixtures" / "flights" / "learn_01.tlog"  # 650 s of flight, 4 packs, 2 ESCs


def _env(cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, PYTHONDONTWRITEBYTECODE="1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    return env


def figure(name: str, argv: list[str], cache_dir: str) -> tuple[dict, bytes]:
    """(wall, CPU and load of one run, its stdout)."""
    t = timed_process(argv, repeat=1, env=_env(cache_dir))
    stdout = t.pop("stdout")
    t = {k: round(v, 2) for k, v in t.items()}
    print(f"{name}: {t['wall_s']:.1f} s wall, {t['cpu_s']:.1f} s CPU (load {t['loadavg_1min']})", flush=True)
    return t, stdout


def wait_for_background_compile(cache_dir: str, timeout_s: float = 1800.0) -> float:
    """Seconds until the cold replay's background compilation (for ``cache_dir``) lets its lock go."""
    from gcs_pdm.compiled import compiling_in_background

    os.environ["NUMBA_CACHE_DIR"] = cache_dir  # the lock is per cache
    started = time.monotonic()
    time.sleep(1.0)  # the detached process takes its lock as it starts
    while compiling_in_background() and time.monotonic() - started < timeout_s:
        time.sleep(1.0)
    return round(time.monotonic() - started, 1)


def _without_timing(stdout: bytes) -> dict:
    summary = json.loads(stdout)
    for key in ("elapsed_s", "messages_per_s"):
        summary.pop(key, None)
    return summary


def main() -> int:
    tlog = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_TLOG
    replay = [sys.executable, "-m", "gcs_pdm.cli", "replay", str(tlog), "--json"]
    prepare = [sys.executable, "-c", "from gcs_pdm.compiled import prepare; from gcs_pdm.service.warm_up import DEMO_GROUPS; prepare(DEMO_GROUPS)"]
    out: dict = {"tlog": str(tlog.relative_to(REPO) if tlog.is_relative_to(REPO) else tlog), "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cold:
        out["replay_cold"], first = figure("replay, cold cache", replay, cold)
        out["background_compile_wall_s"] = wait_for_background_compile(cold)
        print(f"background compilation done {out['background_compile_wall_s']:.0f} s after the cold replay", flush=True)
        out["replay_cached"], cached = figure("replay, cached", replay, cold)
        out["same_summary"] = _without_timing(first) == _without_timing(cached)
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cold:
        out["demo_prepare_cold"], _ = figure("demo's compiled paths, cold cache", prepare, cold)
        out["demo_prepare_cached"], _ = figure("demo's compiled paths, cached", prepare, cold)
    out["demo_prepare_cold"]["wall_idle_bound_s"] = round(out["demo_prepare_cold"]["cpu_s"] / (os.cpu_count() or 1), 1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
