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

The order of the run (``pytest -n N``; pyproject's ``--dist loadgroup``): the tests marked ``slow``
first, so that none of them starts last and leaves the other worker idle, the rest in collection
order. Each test is its own unit of work handed to whichever worker is free, except the tests of a
module that share a module-scoped fixture (a fit, a simulated flight made once): they stay together,
so the fixture is made once (docs/notes/2026-11-27-test-time.md).

The tests that call the library in this process get the commands' one BLAS thread
(``process_threads``): set here, before any test module imports numpy.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gcs_pdm import process_threads

process_threads.one_blas_thread()

REPO = Path(__file__).resolve().parents[1]
WARM_UP_TLOG = REPO / "fixtures" / "flights" / "fault_01.tlog"


#: the demo's groups compiled in parallel children, then one replay (module docstring)
WARM_UP = f"""
import sys
from gcs_pdm.cli import main
from gcs_pdm.compiled import prepare
from gcs_pdm.service.warm_up import DEMO_GROUPS
prepare(DEMO_GROUPS, in_process=False)
sys.exit(main(["replay", {str(WARM_UP_TLOG)!r}, "--json"]))
"""


def pytest_sessionstart(session) -> None:
    if not WARM_UP_TLOG.exists() or session.config.option.collectonly:
        return
    if hasattr(session.config, "workerinput"):
        return  # an xdist worker: the controller warmed the cache before starting it
    # a subprocess, so the test process itself starts as a user's would; its output is of no interest,
    # and a failure here is left to the tests that exercise the replay to report
    subprocess.run([sys.executable, "-c", WARM_UP], cwd=REPO, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, timeout=900, check=False)


#: module-scoped fixtures the xdist units keep together (others are per test or per worker)
SHARED_SCOPES = ("module", "package")


@pytest.hookimpl(tryfirst=True)  # before xdist reads the xdist_group marks (--dist loadgroup)
def pytest_collection_modifyitems(config, items) -> None:
    """Slow tests first; a module's tests that share a module-scoped fixture one xdist unit (module
    docstring). Deterministic, so every worker collects the same order."""
    for item in items:
        if not item.get_closest_marker("xdist_group") and _uses_shared_fixture(item):
            item.add_marker(pytest.mark.xdist_group(item.path.stem))  # test file names are unique
    slow_groups = {_group(i) for i in items if i.get_closest_marker("slow")} - {None}
    items.sort(key=lambda i: not (i.get_closest_marker("slow") or _group(i) in slow_groups))


def _uses_shared_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    return any(d.scope in SHARED_SCOPES for defs in info.name2fixturedefs.values() for d in defs)


def _group(item) -> str | None:
    mark = item.get_closest_marker("xdist_group")
    return None if mark is None else str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
