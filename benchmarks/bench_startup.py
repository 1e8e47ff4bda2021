"""Start-up of ``gcs-pdm replay`` and ``gcs-pdm serve``, and where it goes (issue 18).

    PYTHONPATH=$PWD python benchmarks/bench_startup.py [--repeat 3]

Measured in child processes (wall time and the child's CPU time from ``getrusage``, best of
``--repeat``, with the load average):

- ``python_bare``: ``python -c pass`` — the interpreter alone;
- ``replay_stages``: inside one child, the wall/CPU time of each stage of a replay's start:
  importing the command and the frame mapping, importing the diagnosis pipeline (numpy, numba,
  the kernel), building the pipeline, and the first call of each compiled function (numba loads
  it from its on-disk cache — ``cache=True`` — rather than compiling; the first load of any also
  initialises numba's code generator);
- ``replay_small_json``: the whole ``gcs-pdm replay FILE --json`` on a 300-message tlog (the
  start of a fixture flight), so start-up dominates;
- ``serve_first_http``: ``gcs-pdm serve`` on free ports until ``GET /health`` answers.

Prints one line per figure and, last, one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(REPO))
from measure import loadavg, timed_process  # noqa: E402

STAGES = r'''
import json, sys, time
marks = []
def mark(name):
    marks.append((name, time.perf_counter(), time.process_time()))
mark("start")
import numpy
mark("import_numpy")
import gcs_pdm.cli, gcs_pdm.mavlink.cli, gcs_pdm.mavlink.replay
mark("import_replay_command_and_mapping")
import numba
mark("import_numba")
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
mark("import_diagnosis_pipeline")
p = DiagnosisPipeline()
mark("build_pipeline")
p.estimator.packs.step_one(0, 0.0, 0.0, 20.0, float("nan"), float("nan"))
mark("first_compiled_call_loads_numba")
p.estimator.motors.step_one(0, 0.0, 0.0, 20.0, float("nan"))
from gcs_pdm.models import kernel
x0 = kernel.initial_pack_state(p.estimator.packs.params[:1], 0.9, 20.0)
kernel.simulate_packs(p.estimator.packs.params[:1], x0, numpy.ones(3), numpy.ones(3), 20.0)
mark("other_compiled_functions_from_cache")
out = {b[0]: {"wall_ms": round((b[1] - a[1]) * 1e3, 1), "cpu_ms": round((b[2] - a[2]) * 1e3, 1)}
       for a, b in zip(marks[:-1], marks[1:])}
print(json.dumps(out))
'''


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def small_tlog(path: Path, messages: int = 300) -> Path:
    from gcs_pdm.mavlink.tlog import scan_tlog_bytes

    data = (REPO / "fixtures" / "flights" / "fault_01.tlog").read_bytes()
    ends = [end for *_, end in scan_tlog_bytes(data)]
    path.write_bytes(data[:ends[messages - 1]])
    return path


def serve_first_http(env: dict, repeat: int) -> dict:
    """Wall time from spawning ``gcs-pdm serve`` to the first answer of GET /health, best of repeat."""
    best = float("inf")
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as data:
            port = free_port()
            argv = [sys.executable, "-m", "gcs_pdm.cli", "serve", "--data-dir", data, "--http", f"127.0.0.1:{port}",
                    "--mavlink", f"udpin:127.0.0.1:{free_port()}"]
            started = time.perf_counter()
            proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                while time.perf_counter() - started < 60:
                    try:
                        with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=1) as r:
                            r.read()
                        best = min(best, time.perf_counter() - started)
                        break
                    except OSError:
                        if proc.poll() is not None:
                            raise RuntimeError(f"gcs-pdm serve exited with {proc.returncode}")
                        time.sleep(0.02)
            finally:
                proc.terminate()
                proc.wait(timeout=10)
    return {"wall_s": round(best, 3), "loadavg_1min": loadavg()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
           "GCS_PDM_API_TOKEN": "a-benchmark-token-long-enough"}
    env.pop("GCS_PDM_CONFIG", None)
    out = {"benchmark": "bench_startup"}
    t = timed_process([sys.executable, "-c", "pass"], args.repeat, env)
    out["python_bare"] = {"wall_s": round(t["wall_s"], 3), "cpu_s": round(t["cpu_s"], 3), "loadavg_1min": t["loadavg_1min"]}
    stages = [json.loads(timed_process([sys.executable, "-c", STAGES], 1, env)["stdout"]) for _ in range(args.repeat)]
    out["replay_stages_ms"] = {k: {m: min(s[k][m] for s in stages) for m in ("wall_ms", "cpu_ms")} for k in stages[0]}
    with tempfile.TemporaryDirectory() as tmp:
        small = small_tlog(Path(tmp) / "small.tlog")
        t = timed_process([sys.executable, "-m", "gcs_pdm.cli", "replay", str(small), "--json"], args.repeat, env)
    out["replay_small_json"] = {"wall_s": round(t["wall_s"], 3), "cpu_s": round(t["cpu_s"], 3),
                                "loadavg_1min": t["loadavg_1min"]}
    out["serve_first_http"] = serve_first_http(env, args.repeat)
    print(f"python -c pass                  wall {out['python_bare']['wall_s']:.3f} s cpu {out['python_bare']['cpu_s']:.3f} s")
    for k, v in out["replay_stages_ms"].items():
        print(f"  {k:<40} wall {v['wall_ms']:>7.1f} ms cpu {v['cpu_ms']:>7.1f} ms")
    print(f"gcs-pdm replay (300 msgs) --json wall {out['replay_small_json']['wall_s']:.3f} s "
          f"cpu {out['replay_small_json']['cpu_s']:.3f} s")
    print(f"gcs-pdm serve to first /health  wall {out['serve_first_http']['wall_s']:.3f} s")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
