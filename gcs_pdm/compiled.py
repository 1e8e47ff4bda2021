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

A command that can run without the compiler at a cost it can bear (one replay: the interpreted
pipeline takes 4 s of CPU where compiling it takes about 70 s) calls :func:`interpret_while_cold`
instead: on a cold cache it starts the compilation in the background, niced and detached, for the
next run, and runs itself again at once with ``NUMBA_DISABLE_JIT`` (the same numbers: numba's
interpreted functions are the compiled ones' Python, and what would be too slow in Python has an
array form, ``estimation.held_current_arrays``). One background compilation per cache at a time
(a lock file): a second cold run meanwhile is interpreted again without starting another.

:func:`hold_compiler_at_exit` (``gcs_pdm.cli`` installs it) makes the interpreter's exit wait for a
compilation in progress on another thread and keeps any new one from starting: tearing LLVM and
the interpreter down under a thread that is compiling is what crashed ``gcs-pdm demo`` at exit
(SIGSEGV, or SIGABRT from an LLVM assertion).
"""
from __future__ import annotations

import atexit
import hashlib
import logging
import os
import tempfile
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


def interpreted() -> bool:
    """Whether this process runs numba's functions as Python (``NUMBA_DISABLE_JIT``)."""
    if "numba" not in sys.modules and not os.environ.get("NUMBA_DISABLE_JIT"):
        return False
    from numba import config

    return bool(config.DISABLE_JIT)


def interpret_while_cold(groups_ref: str, out: Callable[[str], None], argv: list[str] | None,
                         interpreting_pays: bool = True) -> None:
    """A command line's first run on a cold cache runs interpreted while the cache fills.

    ``groups_ref``: ``"module:NAME"`` of the command's tuple of groups; ``argv``: the process's
    ``gcs-pdm`` arguments, None when called in-process (a caller's interpreter cannot be replaced:
    then the groups are compiled here, as :func:`prepare`, and so they are when the caller says
    ``interpreting_pays`` is False: a run long enough to cost more interpreted than compiling).
    Cached: returns at once. Cold: starts
    :func:`fill_cache_in_background` (unless one runs) and replaces this process by the same
    command with ``NUMBA_DISABLE_JIT=1`` (never returns). Interpreted already: returns."""
    import importlib

    if interpreted():
        return
    module, _, name = groups_ref.partition(":")
    groups = getattr(importlib.import_module(module), name)
    if all(cached(g) for g in groups):
        return
    if argv is None or os.name != "posix" or not interpreting_pays:
        prepare(groups, out, in_process=False)
        return
    started = fill_cache_in_background(groups_ref)
    out("first run on this machine: the models run interpreted this time (the same numbers) while they "
        + ("compile in the background for the next run (about a minute of CPU)" if started
           else "finish compiling in the background (started by an earlier run)"))
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, "-m", "gcs_pdm.cli", *argv], {**os.environ, "NUMBA_DISABLE_JIT": "1"})


def _lock_path(cache_dir: str | None = None) -> str:
    """The background compilation's lock file, one per numba cache (``cache_dir``, by default
    ``NUMBA_CACHE_DIR`` or the cache beside this package's sources)."""
    where = cache_dir or os.environ.get("NUMBA_CACHE_DIR") or os.path.dirname(os.path.abspath(__file__))
    key = hashlib.sha1(os.path.abspath(where).encode()).hexdigest()[:12]
    return os.path.join(tempfile.gettempdir(), f"gcs-pdm-compiling-{key}.lock")


def _try_lock(path: str):
    """The lock file, open and locked (exclusive, without waiting), or None if another holds it."""
    import fcntl

    handle = open(path, "a")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return None
    return handle


def compiling_in_background() -> bool:
    """Whether a background compilation (:func:`fill_cache_in_background`) holds this cache's lock."""
    handle = _try_lock(_lock_path())
    if handle is None:
        return True
    handle.close()
    return False


def fill_cache_in_background(groups_ref: str) -> bool:
    """Start ``python -m gcs_pdm.compiled --fill-cache groups_ref`` detached (its own session, no
    terminal; it outlives this process), unless one holds the lock; False then."""
    if compiling_in_background():
        return False
    subprocess.Popen([sys.executable, "-m", "gcs_pdm.compiled", "--fill-cache", groups_ref], stdin=subprocess.DEVNULL,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                     env={k: v for k, v in os.environ.items() if k != "NUMBA_DISABLE_JIT"})
    return True


def _fill_cache(groups_ref: str) -> int:
    """The background compilation: niced (the foreground run comes first), under the lock (a
    second one started meanwhile ends at once), each cold group in its own child (:func:`prepare`)."""
    import importlib

    handle = _try_lock(_lock_path())
    if handle is None:
        return 0
    try:
        os.nice(10)
        module, _, name = groups_ref.partition(":")
        prepare(getattr(importlib.import_module(module), name), in_process=False)
    finally:
        handle.close()
    return 0


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
    the cache); the parent names it by ``Group.reference``. ``--fill-cache MODULE:GROUPS``: the
    background compilation of a tuple of groups (:func:`fill_cache_in_background`)."""
    import importlib

    logging.basicConfig(level=logging.WARNING)
    if argv[:1] == ["--fill-cache"]:
        return _fill_cache(argv[1])
    for ref in argv:
        module, _, name = ref.partition(":")
        getattr(importlib.import_module(module), name)()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
