"""gap-validate and the node ask for one BLAS thread before numpy loads (gap_validation/blas.py), unless the
user set the variable; the library leaves the environment alone."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from gap_validation.blas import BLAS_THREAD_VARIABLES

PROBE = ("import os, sys; import {module}; import numpy; "
         "print(','.join(os.environ.get(v, '-') for v in {names!r}))")


def _run(module: str, **env) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    out = subprocess.run([sys.executable, "-c", PROBE.format(module=module, names=BLAS_THREAD_VARIABLES)],
                         env={**clean, **env}, capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1].split(",")


@pytest.mark.parametrize("module", ["gap_validation.cli.main", "gap_validation.ros.main"])
def test_the_entry_points_ask_for_one_thread_unless_told(module):
    assert _run(module) == ["1", "1", "1"]
    assert _run(module, OPENBLAS_NUM_THREADS="2")[0] == "2"


def test_the_library_leaves_the_environment_alone():
    assert _run("gap_validation.core.validator") == ["-", "-", "-"]
