"""The interpreter's exit waits for a numba compilation in progress on another thread (issue 33:
``gcs-pdm demo`` died at exit with SIGSEGV or an LLVM assertion when LLVM was torn down under a
thread still compiling). A daemon thread holds numba's compiler lock, as a compilation does, while
the main thread returns at once; with ``gcs_pdm.compiled.hold_compiler_at_exit`` the process ends
only after the thread has finished and released it."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

SCRIPT = """
import sys, threading, time
from pathlib import Path
from numba.core.compiler_lock import global_compiler_lock
from gcs_pdm import compiled
if sys.argv[1] == "hold":
    compiled.hold_compiler_at_exit()
started = threading.Event()
def compiling():
    with global_compiler_lock:  # what numba holds for a whole compilation
        started.set()
        time.sleep(1.5)
        Path(sys.argv[2]).write_text("finished")
threading.Thread(target=compiling, daemon=True).start()
started.wait()
"""


def _run(mode: str, marker: Path) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-c", SCRIPT, mode, str(marker)], capture_output=True, text=True,
                         cwd=REPO, timeout=60)
    return out, time.monotonic() - t0


@pytest.mark.slow
def test_the_exit_waits_for_a_compilation_in_progress(tmp_path):
    held, _ = _run("hold", tmp_path / "held")
    assert held.returncode == 0, held.stderr
    assert (tmp_path / "held").read_text() == "finished"  # the exit waited for it
    unheld, _ = _run("none", tmp_path / "unheld")
    assert unheld.returncode == 0, unheld.stderr
    assert not (tmp_path / "unheld").exists()  # without the hold the exit does not wait: the case fixed
