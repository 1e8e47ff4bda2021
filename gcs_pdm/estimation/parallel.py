"""Independent pieces of compiled work on up to two threads.

The kernel's functions release the GIL (``nogil=True``), so threads give real parallelism without
a process start-up; the callers split work whose pieces do not depend on each other (Monte Carlo
samples, the packs' health fits), so the results are those of one thread, in the same order.
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: the machine this runs on has two cores; more threads would only queue
MAX_THREADS = 2
_pool: ThreadPoolExecutor | None = None
_making = threading.Lock()


def available_threads() -> int:
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return max(1, min(MAX_THREADS, cpus))


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, on the threads available (in order; exceptions propagate)."""
    items = list(items)
    # serial when there is nothing to share, or when called from one of the pool's own threads
    # (waiting there for the pool would deadlock it)
    if len(items) <= 1 or available_threads() <= 1 or getattr(_inside, "worker", False):
        return [fn(x) for x in items]
    global _pool
    if _pool is None:
        with _making:  # two threads calling first (the service's telemetry and prediction) make one pool
            if _pool is None:
                _pool = ThreadPoolExecutor(max_workers=MAX_THREADS, thread_name_prefix="gcs-pdm-work",
                                           initializer=_mark_worker)
    return list(_pool.map(fn, items))


_inside = threading.local()


def _mark_worker() -> None:
    _inside.worker = True
