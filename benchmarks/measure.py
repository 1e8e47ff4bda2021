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


def host_yardstick_ms() -> float:
    """CPU ms of a fixed compiled loop (512 doubles, L1-resident, no allocation), best of four.

    The host under this VM changes speed in phases of seconds: in its slow phase every compiled
    loop, this one included, takes ~1.4-1.7x the CPU time (no steal time, the other vCPU idle;
    docs/notes/2026-11-27-extended-mc-5.md). Timed just before and after a figure, it says which
    phase the figure was measured in: ~1.2 ms fast, ~2.0 ms slow on this host (Nov 2026)."""
    import numpy as np
    from numba import njit

    global _yardstick
    if _yardstick is None:
        @njit(cache=False)
        def loop(x, n):
            s = 0.0
            for _ in range(n):
                for i in range(x.shape[0]):
                    s += np.exp(-x[i] * 1e-3) * x[i] + s * 1e-9
            return s
        _yardstick = loop
        loop(np.zeros(1), 1)  # compile outside the timing
    x = np.linspace(0.0, 1.0, 512)
    best = float("inf")
    for _ in range(4):
        c0 = time.process_time()
        _yardstick(x, 400)
        best = min(best, time.process_time() - c0)
    return round(best * 1e3, 2)


_yardstick = None
