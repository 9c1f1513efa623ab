"""The CLI pins BLAS threads before numpy loads (the commands import their stack lazily)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer

from app.cli.main import BLAS_THREAD_VARIABLES, pin_blas_threads

ROOT = Path(__file__).resolve().parents[2]


def test_one_thread_unless_asked() -> None:
    environ: dict[str, str] = {}
    assert pin_blas_threads(environ) == 1
    assert {name: environ[name] for name in BLAS_THREAD_VARIABLES} == dict.fromkeys(
        BLAS_THREAD_VARIABLES, "1"
    )


def test_activetouch_blas_threads_wins_and_a_users_own_variable_is_kept() -> None:
    environ = {"ACTIVETOUCH_BLAS_THREADS": "2", "OPENBLAS_NUM_THREADS": "4"}
    assert pin_blas_threads(environ) == 2
    assert all(environ[name] == "2" for name in BLAS_THREAD_VARIABLES)
    own = {"OPENBLAS_NUM_THREADS": "3"}
    assert pin_blas_threads(own) == 3
    assert own["OMP_NUM_THREADS"] == own["MKL_NUM_THREADS"] == "1"


@pytest.mark.parametrize("value", ["0", "two", "-1", ""])
def test_a_bad_thread_count_is_named(value: str) -> None:
    with pytest.raises(typer.BadParameter, match="ACTIVETOUCH_BLAS_THREADS"):
        pin_blas_threads({"ACTIVETOUCH_BLAS_THREADS": value})


def _clean_environment() -> dict[str, str]:
    """This process's environment without any BLAS thread setting (the test command sets
    them; a user's shell does not)."""
    environ = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    environ.pop("ACTIVETOUCH_BLAS_THREADS", None)
    return environ


def test_numpy_loaded_after_pinning_runs_one_thread() -> None:
    """In a fresh process with no BLAS variable set (OpenBLAS would start one thread per core)."""
    script = (
        "from app.cli.main import pin_blas_threads; pin_blas_threads(); "
        "import numpy, scipy.linalg; "
        "from threadpoolctl import threadpool_info; "
        "print(max(i['num_threads'] for i in threadpool_info()))"
    )
    result = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        env=_clean_environment(),
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    assert result.stdout.strip() == "1"


def test_the_cli_refuses_a_bad_thread_count() -> None:
    result = subprocess.run(
        [sys.executable, "-c", "from app.cli.main import main; main()", "--help"],
        cwd=ROOT,
        env={**_clean_environment(), "ACTIVETOUCH_BLAS_THREADS": "many"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert "ACTIVETOUCH_BLAS_THREADS must be a positive integer" in result.stderr
