"""A Dask ``LocalCluster`` for tests: 2 single-threaded worker processes, started once per session.

Registered from ``tests/conftest.py`` (``pytest_plugins``). Starting the cluster costs seconds, so
every module that asks for it shares one: a test must leave it as it found it (cancel or wait for
what it submitted), and may not rely on what earlier tests left on the workers.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import pytest


@pytest.fixture(scope="session")
def dask_cluster() -> Iterator[Any]:
    """A running ``LocalCluster`` (2 worker processes, 1 thread each), closed after the session."""
    from distributed import LocalCluster

    cluster = LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",
        silence_logs=logging.ERROR,
        env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
    )
    try:
        yield cluster
    finally:
        cluster.close()
