"""OpenMP's and OpenBLAS's idle threads sleep (soon) unless the user said otherwise (set before
numba or faiss load libgomp, and before NumPy loads OpenBLAS)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

PIPELINE = str(Path(__file__).resolve().parent.parent / "pipeline")


def _policy_after_import(env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if env_value is not None:
        env["OMP_WAIT_POLICY"] = env_value
    env["PYTHONPATH"] = PIPELINE
    code = "import os, sys; assert 'numba' not in sys.modules; import placeloc; print(os.environ['OMP_WAIT_POLICY'])"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()


def test_importing_placeloc_makes_openmp_threads_sleep_by_default():
    assert _policy_after_import(None) == "PASSIVE"


def test_a_policy_the_user_set_is_kept():
    assert _policy_after_import("ACTIVE") == "ACTIVE"


def _blas_timeout_after_import(env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    if env_value is not None:
        env["OPENBLAS_THREAD_TIMEOUT"] = env_value
    env["PYTHONPATH"] = PIPELINE
    # NumPy must not be loaded yet when placeloc sets it: OpenBLAS reads it as it loads
    code = ("import os, sys; import placeloc; assert 'numpy' not in sys.modules; "
            "print(os.environ['OPENBLAS_THREAD_TIMEOUT'])")
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()


def test_importing_placeloc_shortens_openblas_spinning_by_default():
    assert _blas_timeout_after_import(None) == "20"


def test_an_openblas_timeout_the_user_set_is_kept():
    assert _blas_timeout_after_import("28") == "28"
