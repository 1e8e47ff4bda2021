"""The compiled (numba) paths made ready before they are needed, and never compiled at exit.

numba compiles a function on its first call and keeps it in its on-disk cache (``cache=True``,
``__pycache__`` beside the source or ``NUMBA_CACHE_DIR``). On a fresh install that first call costs
tens of seconds of CPU (docs/performance.md, "Compiling"), and it would land wherever the function
is first called: inside the live loop's telemetry thread while the vehicle flies on, or in a
replay that says nothing meanwhile. So a command that will need them calls :func:`prepare` first:

- each *group* below is a small real workload of the code paths a command runs (the same calls,
  the same argument types, so the same compiled signatures);
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
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

log = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[1]
#: a recorded flight of the paper's aircraft with a motor fault (4 packs, 2 ESCs): what the live
#: loop's estimator, diagnoser and predictions see
WARM_UP_TLOG = REPO / "fixtures" / "flights" / "fault_01.tlog"
#: a progress line only once preparing has taken this long (s), then every PROGRESS_EVERY_S
PROGRESS_AFTER_S = 2.0
PROGRESS_EVERY_S = 30.0


# --- the groups: small real workloads --------------------------------------------------------------

#: the ``filters`` group's pipelines fit no pack-health record: those fits are the ``pack_health``
#: group's, compiled at the same time in another child (a check is due once, with too short a record)
_NO_PACK_FITS = {"check_every_s": math.inf}


def _filters() -> None:
    """The diagnosis pipeline (state estimator, motor diagnosers, prognosis) over a recorded flight,
    as the live loop builds it (``adapters.make_diagnoser``: ``pipeline_for`` the paper's aircraft)
    and a replay runs it; its pack-health fits are the ``pack_health`` group's."""
    from gcs_pdm.diagnosis.pack_health import PackHealthConfig
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog
    from gcs_pdm.models.params import builtin
    from gcs_pdm.vehicle.presets import resolve
    from gcs_pdm.vehicle.replay import pipeline_for, replay_vehicle
    from gcs_pdm.vehicle.telemetry import envelope, frame_mapping

    if not WARM_UP_TLOG.is_file():
        return
    no_fits = PackHealthConfig(**_NO_PACK_FITS)
    diagnoser = pipeline_for(resolve("edge540"), builtin("paper_si"), pack_config=no_fits)
    replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(), frame_consumer=diagnoser.consume)
    # a replay without --vehicle: the description derived from the log (its own motor layout)
    desc, _ = replay_vehicle(WARM_UP_TLOG, None)
    if desc is not None:
        replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)),
                    frame_consumer=pipeline_for(desc, pack_config=no_fits).consume)


def _pack_health() -> None:
    """The pack-health monitor's fits (its cold Gauss-Newton search and a warm check's extension)
    on the recorded flight's pack frames, as the pipeline feeds them (``PackHealthMonitor.add``,
    ``check``), without the filters: the two groups compile in parallel."""
    from gcs_pdm.diagnosis.pack_health import PackHealthMonitor
    from gcs_pdm.frames import PackFrame
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog
    from gcs_pdm.models.params import PACK_NAMES, builtin
    from gcs_pdm.service import adapters

    if not WARM_UP_TLOG.is_file():
        return
    monitor = PackHealthMonitor(adapters.make_estimator(builtin("paper_si")).packs.params.copy())

    def consume(frame) -> None:
        if (isinstance(frame, PackFrame) and frame.pack in PACK_NAMES and frame.voltage_v is not None
                and frame.current_a is not None):
            t = float(frame.time_s)
            monitor.add(PACK_NAMES.index(frame.pack), t, float(frame.current_a), float(frame.voltage_v), 20.0)
            if monitor.due(t):
                monitor.check(t)

    replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(), frame_consumer=consume)


def _held_current() -> None:
    """A replay's trace: the held-current Monte Carlo time to cut-off from an estimator."""
    import numpy as np

    from gcs_pdm.estimation.prediction import predict_packs_at_current
    from gcs_pdm.models.params import builtin
    from gcs_pdm.service import adapters

    est = adapters.make_estimator(builtin("paper_si"))
    n_packs = est.packs.params.shape[0]
    predict_packs_at_current(est, np.full(n_packs, 15.0), current_a=np.full(n_packs, 10.0), horizon_s=120.0,
                             rng=np.random.default_rng(0), n_samples=4)


def _predictions() -> None:
    """The live loop's Monte Carlo predictions from an estimator (time to cut-off, a route's risk),
    the planner's vehicle simulator on the demo's Table III route (as ``demo.table3_mission`` plans
    it) and the simulated vehicle's truth: the whole-vehicle simulation."""
    from gcs_pdm.estimation.prediction import FutureLoad
    from gcs_pdm.models.params import builtin
    from gcs_pdm.planning.plan import make_plan
    from gcs_pdm.planning.simulator import VehicleSimulator, original_order
    from gcs_pdm.planning.table3_scenario import preflight_scenario
    from gcs_pdm.service import adapters
    from gcs_pdm.sim.core import warm_up_kernel
    from gcs_pdm.sim.model import SimConfig
    from gcs_pdm.sim.truth import true_parameters

    import numpy as np

    from gcs_pdm.estimation.prediction import predict_from_estimator

    est = adapters.make_estimator(builtin("paper_si"))
    adapters.prediction_job(est, 3000.0, 20.0, [])()
    load = FutureLoad.constant(3000.0, 600.0, 10.0, 20.0)
    adapters.route_risk(est, load, [], n_samples=8)
    # the diagnoser's prognosis against the mission's load keeps its trajectories' medians
    predict_from_estimator(est, load, rng=np.random.default_rng(0), n_samples=4, trajectories=True)
    scenario = preflight_scenario(10)
    make_plan(VehicleSimulator(scenario, true_parameters()), original_order(scenario), "original")
    warm_up_kernel(SimConfig(limits=scenario.limits.kernel_limits()))


#: group name -> workload; a child process runs ``python -m gcs_pdm.compiled GROUP``
GROUPS: dict[str, Callable[[], None]] = {"filters": _filters, "pack_health": _pack_health,
                                         "held_current": _held_current, "predictions": _predictions}
#: a compiled function of each group whose cache says whether the group is compiled already
_PROBES = {"filters": ("gcs_pdm.estimation.ukf", "pack_step_one"),
           "pack_health": ("gcs_pdm.diagnosis.pack_health", "_run_and_linearise"),
           "held_current": ("gcs_pdm.estimation.prediction", "_held_current_to_cutoff_compiled"),
           "predictions": ("gcs_pdm.models.topology", "_simulate")}
#: what each command runs, the longest to compile first (children start in this order)
DEMO_GROUPS = ("filters", "pack_health", "held_current", "predictions")
REPLAY_GROUPS = ("filters", "pack_health", "held_current")


def cached(group: str) -> bool:
    """Whether numba's on-disk cache holds the group's probe function for this source (its index
    is read as numba reads it: a changed source or another numba makes it stale)."""
    import importlib

    module, name = _PROBES[group]
    try:
        dispatcher = getattr(importlib.import_module(module), name)
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 - numba's private layout changed: treat as cold (costs time, not results)
        return False


def prepare(groups: tuple[str, ...], out: Callable[[str], None] | None = None, *, in_process: bool = True) -> float:
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
            GROUPS[g]()
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


def _compile_in_children(groups: list[str], progress: _Progress) -> None:
    """One child per group, at most one per core at a time; a child that fails is logged (the
    group then compiles here, in this process, as it would have anyway)."""
    waiting = list(groups)
    running: dict[str, subprocess.Popen] = {}
    parallel = max(1, min(os.cpu_count() or 1, len(groups)))
    while waiting or running:
        while waiting and len(running) < parallel:
            g = waiting.pop(0)
            running[g] = subprocess.Popen([sys.executable, "-m", "gcs_pdm.compiled", g], stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(0.25)
        progress.tick()
        for g, proc in list(running.items()):
            if proc.poll() is None:
                continue
            del running[g]
            if proc.returncode != 0:
                err = proc.stderr.read().decode(errors="replace").strip().splitlines()
                log.warning("compiling %s in a child process failed (%s); compiling it here", g,
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
    """``python -m gcs_pdm.compiled GROUP``: one group's workload in a child process (fills the cache)."""
    logging.basicConfig(level=logging.WARNING)
    for g in argv:
        GROUPS[g]()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
