"""Timing helpers shared by the benchmarks: wall time AND process CPU time, with the load average.

On a shared machine wall time measures the neighbours as much as the code; the CPU time this
process (or its children) spent is the figure to trust there. Every figure is reported as
``{"wall_s", "cpu_s", "loadavg_1min"}`` so a reader can tell which.
"""
from __future__ import annotations

import os
import resource
import subprocess
import time


def loadavg() -> float:
    return round(os.getloadavg()[0], 2)


def timed(fn, repeat: int = 3, number: int = 1) -> dict:
    """Best of ``repeat`` runs of ``number`` calls: per-call wall and CPU seconds."""
    best_wall = best_cpu = float("inf")
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        for _ in range(number):
            fn()
        best_cpu = min(best_cpu, (time.process_time() - c0) / number)
        best_wall = min(best_wall, (time.perf_counter() - w0) / number)
    return {"wall_s": best_wall, "cpu_s": best_cpu, "loadavg_1min": loadavg()}


def timed_process(argv: list[str], repeat: int = 3, env: dict | None = None) -> dict:
    """Best of ``repeat`` runs of a whole child process: wall and the child's user+system CPU."""
    best_wall = best_cpu = float("inf")
    out = b""
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        out = subprocess.run(argv, check=True, capture_output=True, env=env).stdout
        wall = time.perf_counter() - w0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        best_wall, best_cpu = min(best_wall, wall), min(best_cpu, cpu)
    return {"wall_s": best_wall, "cpu_s": best_cpu, "loadavg_1min": loadavg(), "stdout": out}


def rate(count: int, t: dict, key: str = "per_s") -> dict:
    """A count over a ``timed`` result as rates on wall and CPU time."""
    return {f"wall_{key}": round(count / t["wall_s"]), f"cpu_{key}": round(count / t["cpu_s"]),
            "wall_s": round(t["wall_s"], 4), "cpu_s": round(t["cpu_s"], 4), "loadavg_1min": t["loadavg_1min"]}
