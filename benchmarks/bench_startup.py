"""Start-up of ``gcs-pdm replay``, ``gcs-pdm serve`` and ``gcs-pdm --help``, and where it goes (issue 18).

    PYTHONPATH=$PWD python benchmarks/bench_startup.py [--repeat 3]

Measured in child processes (wall time and the child's CPU time from ``getrusage``, best of
``--repeat``, with the load average). The children run as an installed package does: with
gcs_pdm's bytecode cached (this machine's shells set ``PYTHONDONTWRITEBYTECODE``, so the benchmark
compiles it into the tree's ``__pycache__`` first, beside numba's caches; git ignores both):

- ``python_bare``: ``python -c pass`` — the interpreter alone;
- ``help``: ``gcs-pdm --help`` (imports no command module);
- ``replay_stages_ms``: inside one child, run as ``gcs-pdm`` runs a command (``gcs_pdm.process_gc``:
  no GC passes over the start, frozen when it is over), the wall/CPU time of each stage of a
  replay's start: numpy; the command, tlog scanner, frame mapping and pymavlink's dialect; numba;
  the vehicle description (pydantic) and the model modules; the diagnosis pipeline's modules;
  building the pipeline (its χ² bounds import ``scipy.special``); then what the first compiled
  call does, split: ``scipy.linalg`` (numba's BLAS check imports it), numba's target context
  (typing and lowering registries, LLVM, its runtime), loading that function from numba's on-disk
  cache (``cache=True``: no compilation); then the other compiled functions; ``gc_cpu_ms``: the
  garbage collector's share of all of it; ``interpreter_exit_cpu_ms``: the child's CPU after its
  last line (module teardown and the interpreter's final collections);
- ``replay_small_json``: the whole ``gcs-pdm replay FILE --json`` on a 300-message tlog (the
  start of a fixture flight), so start-up dominates;
- ``serve_first_http``: ``gcs-pdm serve`` on free ports until ``GET /health`` answers: wall, and
  the CPU the server had used by then (``/proc``).

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
import gc, json, sys, time
marks = []
gc_cpu = [0.0, 0.0]
def gc_timer(phase, info):
    if phase == "start":
        gc_cpu[1] = time.process_time()
    else:
        gc_cpu[0] += time.process_time() - gc_cpu[1]
gc.callbacks.append(gc_timer)
def mark(name):
    marks.append((name, time.perf_counter(), time.process_time()))
from gcs_pdm.process_gc import command, start_up_over
with command():
    mark("start")
    import numpy
    mark("import_numpy")
    import gcs_pdm.cli, gcs_pdm.replay.cli, gcs_pdm.mavlink.replay
    mark("import_replay_command_mapping_pymavlink")
    import numba
    mark("import_numba")
    import gcs_pdm.replay.vehicle
    mark("import_vehicle_description_pydantic_models")
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
    mark("import_diagnosis_pipeline")
    p = DiagnosisPipeline()
    mark("build_pipeline_scipy_special")
    start_up_over()  # where `gcs-pdm replay` says so: before the first message
    import scipy.linalg
    mark("scipy_linalg_for_numba_blas_check")
    from numba.core.registry import cpu_target
    cpu_target.target_context.refresh()
    mark("numba_target_context_registries")
    p.estimator.packs.step_one(0, 0.0, 0.0, 20.0, float("nan"), float("nan"))
    mark("first_compiled_function_from_cache")
    p.estimator.motors.step_one(0, 0.0, 0.0, 20.0, float("nan"))
    from gcs_pdm.models import kernel
    x0 = kernel.initial_pack_state(p.estimator.packs.params[:1], 0.9, 20.0)
    kernel.simulate_packs(p.estimator.packs.params[:1], x0, numpy.ones(3), numpy.ones(3), 20.0)
    mark("other_compiled_functions_from_cache")
out = {b[0]: {"wall_ms": round((b[1] - a[1]) * 1e3, 1), "cpu_ms": round((b[2] - a[2]) * 1e3, 1)}
       for a, b in zip(marks[:-1], marks[1:])}
print(json.dumps({"stages": out, "gc_cpu_ms": round(gc_cpu[0] * 1e3, 1), "cpu_at_end_ms": time.process_time() * 1e3}))
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


def process_cpu_s(pid: int) -> float:
    """User + system CPU seconds a running process has used so far (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def serve_first_http(env: dict, repeat: int) -> dict:
    """From spawning ``gcs-pdm serve`` to the first answer of GET /health: wall, and the server's CPU
    by then; best of repeat."""
    best_wall = best_cpu = float("inf")
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
                        best_wall = min(best_wall, time.perf_counter() - started)
                        best_cpu = min(best_cpu, process_cpu_s(proc.pid))
                        break
                    except OSError:
                        if proc.poll() is not None:
                            raise RuntimeError(f"gcs-pdm serve exited with {proc.returncode}")
                        time.sleep(0.02)
            finally:
                proc.terminate()
                proc.wait(timeout=10)
    return {"wall_s": round(best_wall, 3), "cpu_s": round(best_cpu, 3), "loadavg_1min": loadavg()}


def process_figure(argv: list[str], repeat: int, env: dict) -> dict:
    t = timed_process(argv, repeat, env)
    return {"wall_s": round(t["wall_s"], 3), "cpu_s": round(t["cpu_s"], 3), "loadavg_1min": t["loadavg_1min"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    os.chdir(REPO)  # `python -m`/`-c` put the working directory first on sys.path: this tree's gcs_pdm
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
           "GCS_PDM_API_TOKEN": "a-benchmark-token-long-enough"}
    for name in ("GCS_PDM_CONFIG", "PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX"):
        env.pop(name, None)
    out = {"benchmark": "bench_startup", "bytecode": "cached, as an installed package"}
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(REPO / "gcs_pdm")], env=env, check=True)
    with tempfile.TemporaryDirectory() as tmp:
        small = small_tlog(Path(tmp) / "small.tlog")
        replay = [sys.executable, "-m", "gcs_pdm.cli", "replay", str(small), "--json"]
        out["python_bare"] = process_figure([sys.executable, "-c", "pass"], args.repeat, env)
        out["help"] = process_figure([sys.executable, "-m", "gcs_pdm.cli", "--help"], args.repeat, env)
        stages = []
        for _ in range(args.repeat):
            t = timed_process([sys.executable, "-c", STAGES], 1, env)
            stages.append(json.loads(t["stdout"]))
            stages[-1]["exit_cpu_ms"] = t["cpu_s"] * 1e3 - stages[-1]["cpu_at_end_ms"]  # after the last line
        out["replay_stages_ms"] = {k: {m: min(s["stages"][k][m] for s in stages) for m in ("wall_ms", "cpu_ms")}
                                   for k in stages[0]["stages"]}
        out["replay_stages_ms"]["gc_cpu_ms"] = min(s["gc_cpu_ms"] for s in stages)
        out["replay_stages_ms"]["interpreter_exit_cpu_ms"] = round(min(s["exit_cpu_ms"] for s in stages), 1)
        out["replay_small_json"] = process_figure(replay, args.repeat, env)
        out["serve_first_http"] = serve_first_http(env, args.repeat)
    for name, label in (("python_bare", "python -c pass"), ("help", "gcs-pdm --help")):
        print(f"{label:<40} wall {out[name]['wall_s']:.3f} s cpu {out[name]['cpu_s']:.3f} s")
    for k, v in out["replay_stages_ms"].items():
        if isinstance(v, dict):
            print(f"  {k:<45} wall {v['wall_ms']:>7.1f} ms cpu {v['cpu_ms']:>7.1f} ms")
    print(f"  {'(of which the garbage collector)':<45} cpu {out['replay_stages_ms']['gc_cpu_ms']:>7.1f} ms")
    print(f"  {'the interpreter exiting':<45} cpu {out['replay_stages_ms']['interpreter_exit_cpu_ms']:>7.1f} ms")
    for name, label in (("replay_small_json", "gcs-pdm replay (300 msgs) --json"),
                        ("serve_first_http", "gcs-pdm serve to first /health")):
        print(f"{label:<40} wall {out[name]['wall_s']:.3f} s cpu {out[name]['cpu_s']:.3f} s")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
