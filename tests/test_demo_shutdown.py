"""The demo's start and shutdown, 20 times, each in its own process: no crash at exit (issue 33).

``gcs-pdm demo`` used to die after its summary now and then: SIGSEGV (exit 139) or SIGABRT from an
LLVM assertion, when the interpreter and LLVM were torn down under a thread still compiling numba
code. Each run here starts the service, its HTTP API and the simulated vehicle, flies two wall
seconds (the service's threads busy in compiled code, or compiling it on a cold cache) and shuts
down as the demo does; the process must then exit 0, with no fatal error on stderr.
"""
from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RUNS = 20

START_AND_SHUT_DOWN = """
import logging, sys
from gcs_pdm import compiled
from gcs_pdm.service.demo import print_summary, run_demo
compiled.hold_compiler_at_exit()  # as gcs_pdm.cli.main installs it
logging.basicConfig(level=logging.ERROR)
result = run_demo(http_port=0, timeout_s=2.0, compare=False, prepare=False, hold_while_deciding=True,
                  out=lambda line: None)
print_summary(result, out=lambda line: None)
print("shut down", result.sim_time_s > 0)
"""


def _run(i: int) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", START_AND_SHUT_DOWN], capture_output=True, text=True, cwd=REPO,
                          timeout=600)


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_twenty_demo_shutdowns_exit_cleanly():
    first = _run(0)  # alone: on a cold cache it compiles, the others then load
    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = [first, *pool.map(_run, range(1, RUNS))]
    # a crash is a signal (exit 139 SIGSEGV, 134 SIGABRT, or negative from subprocess) or a fatal
    # error on stderr; a logged exception of the service's (a mission download cut short by the
    # shutdown) is not one
    bad = [(i, out.returncode, out.stderr[-2000:]) for i, out in enumerate(runs)
           if out.returncode != 0 or "shut down True" not in out.stdout
           or any(fatal in out.stderr for fatal in ("Fatal Python error", "Assertion", "Segmentation fault"))]
    assert not bad, bad
