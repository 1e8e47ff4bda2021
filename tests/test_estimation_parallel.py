"""The thread helper the Monte Carlo and the pack-health fits share (issue 18)."""
from __future__ import annotations

from gcs_pdm.estimation.parallel import thread_map


def test_thread_map_keeps_order_and_runs_nested_calls_serially():
    assert thread_map(lambda x: x * x, range(7)) == [0, 1, 4, 9, 16, 25, 36]
    # a nested call from a worker must not wait for the (busy) pool
    assert thread_map(lambda x: sum(thread_map(lambda y: y + x, range(3))), range(4)) == [3, 6, 9, 12]


def test_the_pool_is_made_once_when_two_threads_first_call_at_once(monkeypatch):
    """The service's telemetry thread (pack-health fits) and its prediction thread (Monte Carlo)
    may both call first: one pool, not one each (the other's threads would idle for the process's life)."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    from gcs_pdm.estimation import parallel

    made = []

    class SlowToMake(ThreadPoolExecutor):
        def __init__(self, *args, **kwargs):
            made.append(self)
            time.sleep(0.2)  # both callers find no pool while the first is made
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(parallel, "_pool", None)
    monkeypatch.setattr(parallel, "ThreadPoolExecutor", SlowToMake)
    monkeypatch.setattr(parallel, "available_threads", lambda: 2)
    results = []
    callers = [threading.Thread(target=lambda: results.append(thread_map(abs, [-1, -2]))) for _ in range(2)]
    for c in callers:
        c.start()
    for c in callers:
        c.join()
    try:
        assert results == [[1, 2], [1, 2]] and len(made) == 1
    finally:
        for pool in made:
            pool.shutdown()
