"""Session set-up shared by every test directory.

Numba keeps its compiled functions in an on-disk cache next to the sources (``cache=True``). A fresh
clone has none, and the first process to need a function compiles it — tens of seconds for the
estimator's, the diagnoser's and the kernel's under load. The browser tests run first and start the
service in a subprocess whose first telemetry frames would pay that compilation inside the tests'
timeouts. One replay of a fixture flight before the session compiles (or, with a warm cache, only
loads) what the live path uses, so every test sees the start-up a user sees after installing. It
also fills the cache for the demo's groups (``gcs_pdm.service.warm_up.DEMO_GROUPS``: the Monte Carlo
predictions, the planner's and the simulated vehicle's kernel), one child process per group on all
cores: without it both xdist workers compiled the same functions at once in their first demo test.
Under xdist it runs once, in the controller, before the workers start (they share the on-disk cache).

Before it, the package's bytecode is written once (``compileall``): with ``PYTHONDONTWRITEBYTECODE``
set, as on this machine and in CI, no process writes it, so every Python the suite starts (each
``gcs-pdm`` command, demo and service of the subprocess tests, the workers) compiled all of
``gcs_pdm`` from source again: 0.3-0.7 s of CPU each (docs/notes/2026-11-27-test-time-2.md).

The order of the run under xdist: the tests marked ``slow`` first, each test to the next free
worker, a module's tests sharing a module-scoped fixture together (``tests/run_order.py``).

The tests that call the library in this process get the commands' one BLAS thread
(``process_threads``): set here, before any test module imports numpy.
"""
from __future__ import annotations

import compileall
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from gcs_pdm import process_threads

sys.path.insert(0, str(Path(__file__).parent))  # tests/ is not a package
from run_order import order_for_xdist  # noqa: E402

process_threads.one_blas_thread()

REPO = Path(__file__).resolve().parents[1]
WARM_UP_TLOG = REPO / "fixtures" / "flights" / "fault_01.tlog"


#: the demo's groups (the replay's among them) compiled in parallel children, then one replay (module docstring)
WARM_UP = f"""
import sys
from gcs_pdm.cli import main
from gcs_pdm.compiled import prepare
from gcs_pdm.service.warm_up import DEMO_GROUPS
# the demo's groups hold the replay's: on a cold cache a replay in a subprocess would run
# interpreted and leave the compiling to a background process (compiled.interpret_while_cold)
prepare(DEMO_GROUPS, in_process=False)
sys.exit(main(["replay", {str(WARM_UP_TLOG)!r}, "--json"]))
"""


def pytest_sessionstart(session) -> None:
    if session.config.option.collectonly or hasattr(session.config, "workerinput"):
        return  # an xdist worker: the controller wrote the bytecode and warmed the cache before starting it
    # Python checks each .pyc against its source's mtime, so a stale one is never read; a tree it
    # cannot write to only leaves the processes compiling, as before
    compileall.compile_dir(REPO / "gcs_pdm", quiet=2)
    if not WARM_UP_TLOG.exists():
        return
    # a subprocess, so the test process itself starts as a user's would; its output is of no interest,
    # and a failure here is left to the tests that exercise the replay to report
    subprocess.run([sys.executable, "-c", WARM_UP], cwd=REPO, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, timeout=900, check=False)


def pytest_configure(config) -> None:
    """``-n N`` without a ``--dist`` of the caller's: ``--dist loadgroup --no-loadscope-reorder``
    (``tests/run_order.py``). Set here, not in pyproject's addopts, so that a run without xdist
    (``-p no:xdist``) still parses its options; the workers get the controller's options."""
    config.addinivalue_line("markers", "xdist_group(name): tests/run_order.py's units of work (pytest-xdist)")
    if getattr(config.option, "dist", "no") == "load" and not _dist_given(config):
        config.option.dist = "loadgroup"
        config.option.loadscopereorder = False
    if getattr(config, "workerinput", {}).get(LOADGROUP):
        config.option.loadgroup = True  # a worker parses the command line, not the controller's choice


#: the workerinput key that tells a worker the controller chose ``--dist loadgroup``
LOADGROUP = "gcs_pdm_loadgroup"


@pytest.hookimpl(optionalhook=True)  # an xdist hook: absent without xdist
def pytest_configure_node(node) -> None:
    node.workerinput[LOADGROUP] = node.config.option.dist == "loadgroup"


def _dist_given(config) -> bool:
    args = [*config.invocation_params.args, *shlex.split(os.environ.get("PYTEST_ADDOPTS", ""))]
    return any(a in ("-d", "--distload", "--dist") or a.startswith("--dist=") for a in map(str, args))


@pytest.hookimpl(tryfirst=True)  # before xdist reads the xdist_group marks (--dist loadgroup)
def pytest_collection_modifyitems(config, items) -> None:
    order_for_xdist(items)
