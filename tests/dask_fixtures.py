"""A Dask ``LocalCluster`` for tests: 2 single-threaded worker processes, started once per module.

Registered from ``tests/conftest.py`` (``pytest_plugins``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import pytest


@pytest.fixture(scope="module")
def dask_cluster() -> Iterator[Any]:
    """A running ``LocalCluster`` (2 worker processes, 1 thread each); closed after the module."""
    from distributed import LocalCluster

    cluster = LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.ERROR,
        env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
    )
    try:
        yield cluster
    finally:
        cluster.close()
