"""The thread helper the Monte Carlo and the pack-health fits share (issue 18)."""
from __future__ import annotations

from gcs_pdm.estimation.parallel import thread_map


def test_thread_map_keeps_order_and_runs_nested_calls_serially():
    assert thread_map(lambda x: x * x, range(7)) == [0, 1, 4, 9, 16, 25, 36]
    # a nested call from a worker must not wait for the (busy) pool
    assert thread_map(lambda x: sum(thread_map(lambda y: y + x, range(3))), range(4)) == [3, 6, 9, 12]
