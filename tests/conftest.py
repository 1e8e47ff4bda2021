"""Session set-up shared by every test directory.

Numba keeps its compiled functions in an on-disk cache next to the sources (``cache=True``). A fresh
clone has none, and the first process to need a function compiles it — tens of seconds for the
estimator's, the diagnoser's and the kernel's under load. The browser tests run first and start the
service in a subprocess whose first telemetry frames would pay that compilation inside the tests'
timeouts. Compiling the replay's groups and one replay of a fixture flight before the session
compile (or, with a warm cache, only load) what the live path uses, so every test sees the
start-up a user sees after installing.

The tests that call the library in this process get the commands' one BLAS thread
(``process_threads``): set here, before any test module imports numpy.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from gcs_pdm import process_threads

process_threads.one_blas_thread()

REPO = Path(__file__).resolve().parents[1]
WARM_UP_TLOG = REPO / "fixtures" / "flights" / "fault_01.tlog"


def pytest_sessionstart(session) -> None:
    if not WARM_UP_TLOG.exists():
        return
    # subprocesses, so the test process itself starts as a user's would; their output is of no
    # interest, and a failure here is left to the tests that exercise the replay to report. The
    # replay's groups are compiled first: on a cold cache a replay alone would run interpreted and
    # leave the compiling to a background process (compiled.interpret_while_cold)
    warm = "from gcs_pdm.compiled import prepare; from gcs_pdm.replay.warm_up import REPLAY_GROUPS; " \
           "prepare(REPLAY_GROUPS, in_process=False)"
    for argv in (["-c", warm], ["-m", "gcs_pdm.cli", "replay", str(WARM_UP_TLOG), "--json"]):
        subprocess.run([sys.executable, *argv], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       timeout=900, check=False)
