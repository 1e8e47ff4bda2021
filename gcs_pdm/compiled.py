"""The compiled (numba) paths made ready before they are needed, and never compiled at exit.

numba compiles a function on its first call and keeps it in its on-disk cache (``cache=True``,
``__pycache__`` beside the source or ``NUMBA_CACHE_DIR``). On a fresh install that first call costs
tens of seconds of CPU (docs/performance.md, "Compiling"), and it would land wherever the function
is first called: inside the live loop's telemetry thread while the vehicle flies on, or in a
replay that says nothing meanwhile. So a command that will need them calls :func:`prepare` first:

- each *group* (:class:`Group`) is a small real workload of the code paths a command runs (the
  same calls, the same argument types, so the same compiled signatures), defined beside the code
  it warms: ``gcs_pdm.replay.warm_up`` (the replay's), ``gcs_pdm.service.warm_up`` (the demo's);
- when a group's cache is cold, the groups are compiled in parallel, one child process each (one
  per core at a time; numba's compiler holds a process-wide lock, so threads would not overlap),
  each writing numba's cache; then every group runs here, loading what the children wrote;
- a progress line on stderr when it takes long ("preparing compiled models… 12 s").

:func:`hold_compiler_at_exit` (``gcs_pdm.cli`` installs it) makes the interpreter's exit wait for a
compilation in progress on another thread and keeps any new one from starting: tearing LLVM and
the interpreter down under a thread that is compiling is what crashed ``gcs-pdm demo`` at exit
(SIGSEGV, or SIGABRT from an LLVM assertion).
"""
from __future__ import annotations

import atexit
import logging
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Callable

log = logging.getLogger(__name__)

#: a progress line only once preparing has taken this long (s), then every PROGRESS_EVERY_S
PROGRESS_AFTER_S = 2.0
PROGRESS_EVERY_S = 30.0


@dataclass(frozen=True)
class Group:
    """A small real workload of the code paths a command runs, defined beside that code
    (``gcs_pdm.replay.warm_up``, ``gcs_pdm.service.warm_up``): this module only runs groups, so it
    imports no layer above it."""
    name: str
    #: a module-level function (a child process imports it by ``module:name``)
    workload: Callable[[], None]
    #: (module, compiled function) whose on-disk cache says whether the group is compiled already
    probe: tuple[str, str]

    @property
    def reference(self) -> str:
        return f"{self.workload.__module__}:{self.workload.__qualname__}"


def cached(group: Group) -> bool:
    """Whether numba's on-disk cache holds the group's probe function for this source (its index
    is read as numba reads it: a changed source or another numba makes it stale)."""
    import importlib

    module, name = group.probe
    try:
        dispatcher = getattr(importlib.import_module(module), name)
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 - numba's private layout changed: treat as cold (costs time, not results)
        return False


def prepare(groups: tuple[Group, ...], out: Callable[[str], None] | None = None, *, in_process: bool = True) -> float:
    """Make ``groups`` compiled (module docstring); returns the wall seconds it took. ``out``: where
    the progress line goes (the log by default). ``in_process=False``: only fill the cache."""
    say = out or log.warning  # a CLI passes its own printer; library code does not print
    started = time.monotonic()
    cold = [g for g in groups if not cached(g)]
    progress = _Progress(say, started)
    if cold:
        _compile_in_children(cold, progress)
    if in_process:
        for g in groups:
            g.workload()
            progress.tick()
    elapsed = time.monotonic() - started
    progress.done(elapsed)
    return elapsed


class _Progress:
    def __init__(self, say, started: float):
        self.say, self.started, self.last = say, started, None

    def tick(self) -> None:
        now = time.monotonic()
        if now - self.started >= PROGRESS_AFTER_S and (self.last is None or now - self.last >= PROGRESS_EVERY_S):
            self.last = now
            self.say(f"preparing compiled models… {now - self.started:.0f} s")

    def done(self, elapsed: float) -> None:
        if self.last is not None:
            self.say(f"compiled models ready in {elapsed:.0f} s (cached for the next run)")


def _compile_in_children(groups: list[Group], progress: _Progress) -> None:
    """One child per group, at most one per core at a time; a child that fails is logged (the
    group then compiles here, in this process, as it would have anyway)."""
    waiting = list(groups)
    running: dict[Group, subprocess.Popen] = {}
    parallel = max(1, min(os.cpu_count() or 1, len(groups)))
    while waiting or running:
        while waiting and len(running) < parallel:
            g = waiting.pop(0)
            running[g] = subprocess.Popen([sys.executable, "-m", "gcs_pdm.compiled", g.reference], stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(0.25)
        progress.tick()
        for g, proc in list(running.items()):
            if proc.poll() is None:
                continue
            del running[g]
            if proc.returncode != 0:
                err = proc.stderr.read().decode(errors="replace").strip().splitlines()
                log.warning("compiling %s in a child process failed (%s); compiling it here", g.name,
                            err[-1] if err else f"exit {proc.returncode}")
            proc.stderr.close()


# --- the exit -----------------------------------------------------------------------------------

_exit_hold_installed = False


def hold_compiler_at_exit() -> None:
    """At the interpreter's exit, wait for a numba compilation in progress on another thread, then
    hold numba's compiler lock so none starts while the interpreter and LLVM are torn down.
    Installed once; a no-op when numba was never imported."""
    global _exit_hold_installed
    if not _exit_hold_installed:
        atexit.register(_hold_compiler)
        _exit_hold_installed = True


#: how long the exit waits for another thread's compilation (s); then it exits anyway, as before
EXIT_WAIT_S = 300.0


def _hold_compiler() -> None:
    if "numba" not in sys.modules:
        return
    from numba.core.compiler_lock import global_compiler_lock

    lock = getattr(global_compiler_lock, "_lock", None)
    if lock is None:
        return
    if not lock.acquire(timeout=EXIT_WAIT_S):
        log.warning("exit: a compilation on another thread did not finish in %.0f s", EXIT_WAIT_S)
    # never released: the process is ending, and no thread may start compiling from here


def main(argv: list[str]) -> int:
    """``python -m gcs_pdm.compiled MODULE:FUNCTION``: one group's workload in a child process (fills
    the cache); the parent names it by ``Group.reference``."""
    import importlib

    logging.basicConfig(level=logging.WARNING)
    for ref in argv:
        module, _, name = ref.partition(":")
        getattr(importlib.import_module(module), name)()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
