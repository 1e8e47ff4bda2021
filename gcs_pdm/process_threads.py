"""One BLAS thread per ``gcs-pdm`` command (docs/performance.md, "BLAS threads").

numpy and scipy each load their own OpenBLAS, and each OpenBLAS starts a thread per core whose
workers spin while they wait for work. gcs-pdm's matrices are small (a filter's 4×4 covariance, a
pack-health fit's three-column least squares, a fit's Jacobian of a few dozen columns): a second
BLAS thread never pays for its hand-over, and the spinning takes the second core from the threads
that do pay (the replay's trace worker, the pack-health fits on threads, numba's parallel kernel).
Measured on this 2-core machine: a 100k-message replay 0.2–0.35 s less CPU with the same output,
the PyBaMM fits 15–20 % less CPU with the same parameters.

So ``gcs_pdm.cli.main`` calls :func:`one_blas_thread` before any command imports numpy. A value the
user set is kept (``OPENBLAS_NUM_THREADS=2 gcs-pdm fit …``). Subprocesses a command starts inherit it.
"""
from __future__ import annotations

import os

#: the variables the BLAS libraries read when they load (numpy's and scipy's wheels ship OpenBLAS)
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS",)


def one_blas_thread() -> None:
    """Ask the BLAS libraries loaded after this call for one thread, unless the user chose."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
