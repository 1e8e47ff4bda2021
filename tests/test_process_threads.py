"""A ``gcs-pdm`` command runs with one BLAS thread unless the user chose (gcs_pdm/process_threads.py)."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from gcs_pdm import cli

# the threads of a fresh interpreter after importing numpy and scipy's BLAS, as /proc counts them
_COUNT_THREADS = ("import numpy, scipy.linalg, os; numpy.ones((64, 64)) @ numpy.ones((64, 64)); "
                  "print(len(os.listdir('/proc/self/task')))")


def _threads_after(prelude: str, env: dict[str, str]) -> int:
    out = subprocess.run([sys.executable, "-c", prelude + _COUNT_THREADS], env=env, check=True,
                         capture_output=True, text=True).stdout
    return int(out.strip().splitlines()[-1])


def _env_without_blas_settings() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="thread count read from /proc (Linux)")
def test_one_blas_thread_leaves_numpy_and_scipy_with_no_worker_threads():
    env = _env_without_blas_settings()
    with_setting = _threads_after("from gcs_pdm import process_threads; process_threads.one_blas_thread(); ", env)
    assert with_setting == 1
    if (os.cpu_count() or 1) > 1:  # on one core OpenBLAS starts no worker anyway
        assert _threads_after("", env) > 1


def test_the_command_sets_it_before_the_command_runs_and_keeps_the_users_choice(monkeypatch):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    with pytest.raises(SystemExit):
        cli.main(["vehicle", "--help"])
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    with pytest.raises(SystemExit):
        cli.main(["vehicle", "--help"])
    assert os.environ["OPENBLAS_NUM_THREADS"] == "2"
