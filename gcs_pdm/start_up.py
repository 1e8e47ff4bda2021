"""A command's start-up, as far as the process is concerned: the garbage collector (docs/performance.md,
"Start-up breakdown").

``gcs_pdm.cli.main`` runs every command inside :func:`starting`; a command calls
:func:`start_up_over` once its imports and set-up are done (``replay`` before the first message,
``serve`` before it opens its link). State lives here, not in ``gcs_pdm.cli``: under
``python -m gcs_pdm.cli`` that module is ``__main__`` and a second import would be a second copy.
"""
from __future__ import annotations

import gc
from contextlib import contextmanager

#: the cyclic garbage collector's generation-0 threshold while a command starts (CPython's: 700).
#: A start imports numpy, numba, pydantic and fills numba's typing registries: some 10^5 long-lived
#: container objects, which the default thresholds traverse again and again (full collections
#: included) for nothing: a tenth of a replay's start. The higher threshold still collects, so
#: garbage stays bounded in a command that never calls start_up_over().
START_UP_GC_THRESHOLD = 300_000
_gc_thresholds: tuple[int, ...] | None = None  # the ones to restore while a command is starting
_gc_frozen = False


def start_up_over() -> None:
    """A command's imports and set-up are done: freeze what the start created (``gc.freeze``: the
    collector never traverses it again) and collect at the usual thresholds from here. A no-op
    outside :func:`starting` and after the first call."""
    global _gc_thresholds, _gc_frozen
    if _gc_thresholds is not None:
        gc.freeze()
        gc.set_threshold(*_gc_thresholds)
        _gc_thresholds, _gc_frozen = None, True


@contextmanager
def starting():
    """Around a command: the start-up threshold until start_up_over(); on the way out everything as it
    was (``gcs_pdm.cli.main`` may run inside another process: tests, the service's demo)."""
    global _gc_thresholds, _gc_frozen
    if _gc_thresholds is not None or _gc_frozen:  # nested: the outer one decides
        yield
        return
    _gc_thresholds = gc.get_threshold()
    gc.set_threshold(START_UP_GC_THRESHOLD, *_gc_thresholds[1:])
    try:
        yield
    finally:
        if _gc_thresholds is not None:
            gc.set_threshold(*_gc_thresholds)
        if _gc_frozen:
            gc.unfreeze()
        _gc_thresholds, _gc_frozen = None, False
