"""The cyclic garbage collector around a ``gcs-pdm`` command (docs/performance.md, "Start-up breakdown").

A command's start imports numpy, numba, scipy, pydantic and fills numba's typing registries: some
10^5-10^6 long-lived container objects. With CPython's thresholds the collector traverses them
again and again while they are created (a tenth of a replay's start), and the interpreter's exit
traverses them all again in several full collections (0.5 s of a 300-message replay, more than
its messages). Neither finds garbage worth the time. So ``gcs_pdm.cli.main`` runs every command
inside :func:`command`:

- until the command calls :func:`start_up_over` (``replay`` before its first message, ``serve``
  before it opens its link), generation 0 is collected every ``START_UP_GC_THRESHOLD``
  allocations instead of 700 (still collected: garbage stays bounded in a command that never
  calls it); then what the start created is frozen (``gc.freeze``: never traversed again) and the
  usual thresholds return;
- at the process's exit everything left is frozen before the interpreter's final collections;
  objects are still freed by reference counting as modules are torn down, and ``atexit``
  handlers (temporary directories, thread pools, logging) run before it, as always.

State lives here, not in ``gcs_pdm.cli``: under ``python -m gcs_pdm.cli`` that module is
``__main__``, and importing it again would make a second copy.
"""
from __future__ import annotations

import atexit
import gc
from contextlib import contextmanager

#: generation 0's threshold while a command starts (CPython's is 700)
START_UP_GC_THRESHOLD = 300_000
_thresholds: tuple[int, ...] | None = None  # the ones to restore, while a command is starting
_frozen = False
_freeze_at_exit_registered = False


def start_up_over() -> None:
    """A command's imports and set-up are done: freeze what the start created and collect at the
    usual thresholds from here. A no-op outside :func:`command` and after the first call."""
    global _thresholds, _frozen
    if _thresholds is not None:
        gc.freeze()
        gc.set_threshold(*_thresholds)
        _thresholds, _frozen = None, True


@contextmanager
def command():
    """Around a command: the start-up threshold until start_up_over(), the freeze at the process's
    exit; on the way out the thresholds and generations as they were (``gcs_pdm.cli.main`` may run
    inside another process: tests, the service's demo)."""
    global _thresholds, _frozen, _freeze_at_exit_registered
    if not _freeze_at_exit_registered:
        # atexit runs the last registered first: this one after whatever the command registered
        atexit.register(gc.freeze)
        _freeze_at_exit_registered = True
    if _thresholds is not None or _frozen:  # nested: the outer one decides
        yield
        return
    _thresholds = gc.get_threshold()
    gc.set_threshold(START_UP_GC_THRESHOLD, *_thresholds[1:])
    try:
        yield
    finally:
        if _thresholds is not None:
            gc.set_threshold(*_thresholds)
        if _frozen:
            gc.unfreeze()
        _thresholds, _frozen = None, False
