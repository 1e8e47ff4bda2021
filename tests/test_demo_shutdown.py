"""The demo's start and shutdown, 10 times, each in its own process: no crash at exit (issue 33).

``gcs-pdm demo`` used to die after its summary now and then: SIGSEGV (exit 139) or SIGABRT from an
LLVM assertion, when the interpreter and LLVM were torn down under a thread still compiling numba
code. Each run here starts the service, its HTTP API and the simulated vehicle, flies two wall
seconds (the service's threads busy in compiled code, or compiling it on a cold cache) and shuts
down as the demo does; the process must then exit 0, with no fatal error on stderr. The cause itself
(the exit not waiting for a compilation in progress) is tested deterministically in
``test_compiled_exit.py``; these runs check the whole start and shutdown around it. 10 runs, not 20:
the 20 took 140 s of one worker, the suite's longest test (docs/notes/2026-11-27-test-time-3.md).
"""
from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RUNS = 10

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
def test_ten_demo_shutdowns_exit_cleanly():
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


def test_an_unanswered_proposal_holds_the_demo_clock_only_for_a_while(monkeypatch):
    """The tests' demo holds the vehicle's clock while a proposal waits for the operator; its
    operator approves only feasible proposals, so an infeasible one would hold the clock for ever
    (CI: the advise demo 'still flying' at its timeout). The hold lets go after OPERATOR_WAIT_S."""
    import time
    from types import SimpleNamespace

    from gcs_pdm.service.demo import DecisionHold

    proposed = [{"id": 3}]
    service = SimpleNamespace(
        loop=SimpleNamespace(telemetry=SimpleNamespace(time_s=100.0), executor=SimpleNamespace(working=False)),
        store=SimpleNamespace(plans=lambda status=None, limit=100: list(proposed) if status == "proposed" else []))
    monkeypatch.setattr(DecisionHold, "OPERATOR_WAIT_S", 0.3)
    monkeypatch.setattr(DecisionHold, "PROPOSALS_EVERY_S", 0.0)
    hold = DecisionHold(service)
    hold.vehicle = SimpleNamespace(core=SimpleNamespace(time_s=101.0))
    assert hold() is True                 # a fresh proposal waits for the operator
    time.sleep(0.4)
    assert hold() is False                # nobody answered: the aircraft flies on
    proposed[:] = [{"id": 4}]
    assert hold() is True                 # a new proposal holds again
    proposed.clear()
    assert hold() is False


def test_a_service_whose_telemetry_stands_still_does_not_hold_the_vehicle_for_ever(monkeypatch):
    """The hold waits while the service's telemetry lags the vehicle's; if the service's time stands
    still (its clock waiting to confirm a forward step that only the vehicle's later messages can
    confirm) the vehicle flies on after LAG_STALL_S, and a moving service time holds again."""
    import time
    from types import SimpleNamespace

    from gcs_pdm.service.demo import DecisionHold

    telemetry = SimpleNamespace(time_s=72.0)
    service = SimpleNamespace(
        loop=SimpleNamespace(telemetry=telemetry, executor=SimpleNamespace(working=False)),
        store=SimpleNamespace(plans=lambda status=None, limit=100: []))
    monkeypatch.setattr(DecisionHold, "LAG_STALL_S", 0.3)
    monkeypatch.setattr(DecisionHold, "PROPOSALS_EVERY_S", 0.0)
    hold = DecisionHold(service)
    hold.vehicle = SimpleNamespace(core=SimpleNamespace(time_s=75.5))
    assert hold() is True                 # the service has not seen the last 3.5 s yet
    time.sleep(0.4)
    assert hold() is False                # it stood still: the vehicle's next messages are what it waits for
    telemetry.time_s = 72.2               # it moved, and still lags: hold again
    assert hold() is True
    hold.vehicle.core.time_s = 74.0       # caught up to within LAG_S
    assert hold() is False
