"""A newcomer's first run (issue 33): ``gcs-pdm replay`` of a 650-s tlog from a cold numba cache,
the same replay once cached, and the demo's preparation of its compiled paths from a cold cache.

    PYTHONPATH=$PWD python benchmarks/bench_first_run.py [TLOG]

"Cold" is a fresh, empty ``NUMBA_CACHE_DIR`` per measurement (nothing compiled, as after a fresh
clone); each figure is one child process (start-up included): wall and CPU seconds (the child's and
its own children's: the compile workers) and the load average, since on a shared machine the wall
time measures the neighbours too. The CPU time spread over the cores is the wall time an idle
machine would take at best (``wall_idle_bound_s``: CPU / cores, not below the longest serial part).
Prints a line per figure and, last, one JSON object.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import timed_process  # noqa: E402

DEFAULT_TLOG = REPO / "fixtures" / "flights" / "learn_01.tlog"  # 650 s of flight, 4 packs, 2 ESCs


def _env(cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, PYTHONDONTWRITEBYTECODE="1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    return env


def figure(name: str, argv: list[str], cache_dir: str) -> dict:
    t = timed_process(argv, repeat=1, env=_env(cache_dir))
    t.pop("stdout")
    t = {k: round(v, 2) for k, v in t.items()}
    print(f"{name}: {t['wall_s']:.1f} s wall, {t['cpu_s']:.1f} s CPU (load {t['loadavg_1min']})", flush=True)
    return t


def main() -> int:
    tlog = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_TLOG
    replay = [sys.executable, "-m", "gcs_pdm.cli", "replay", str(tlog), "--json"]
    prepare = [sys.executable, "-c", "from gcs_pdm.compiled import prepare; from gcs_pdm.service.warm_up import DEMO_GROUPS; prepare(DEMO_GROUPS)"]
    out: dict = {"tlog": str(tlog.relative_to(REPO) if tlog.is_relative_to(REPO) else tlog), "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cold:
        out["replay_cold"] = figure("replay, cold cache", replay, cold)
        out["replay_cached"] = figure("replay, cached", replay, cold)
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cold:
        out["demo_prepare_cold"] = figure("demo's compiled paths, cold cache", prepare, cold)
        out["demo_prepare_cached"] = figure("demo's compiled paths, cached", prepare, cold)
    for key in ("replay_cold", "demo_prepare_cold"):
        out[key]["wall_idle_bound_s"] = round(out[key]["cpu_s"] / (os.cpu_count() or 1), 1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
