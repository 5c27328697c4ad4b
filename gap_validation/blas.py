"""One BLAS thread for ``gap-validate`` and the node, unless the user chose otherwise.

The estimator's work is many small matrix products (a trim segment's regression is 2000 x 25, a record's
spectra a few hundred lines); OpenBLAS's threads give nothing there and, when the cores are busy (replays side
by side, a node beside a flight stack, a campaign's workers), they spin while waiting for each other. Measured
on a ten-minute DataFlash replay on this 2-core machine with two other jobs running: 10.5-13.4 s with
OpenBLAS's default threads, 4.7-6.9 s with one. The entry points (:mod:`gap_validation.cli.main`,
:mod:`gap_validation.ros.main`) call
:func:`single_threaded_blas` before anything imports numpy; the library leaves the environment alone.
"""
from __future__ import annotations

import os
import sys

__all__ = ["single_threaded_blas", "BLAS_THREAD_VARIABLES"]

#: The variables OpenBLAS, OpenMP and MKL read at load time.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> bool:
    """Ask for one BLAS thread where the environment says nothing; False when numpy is loaded already (too
    late to matter: BLAS reads the variables when it loads)."""
    if "numpy" in sys.modules:
        return False
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
    return True
