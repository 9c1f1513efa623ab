"""A Dask ``LocalCluster`` for tests: 2 single-threaded worker processes, started once per session.

Registered from ``tests/conftest.py`` (``pytest_plugins``). Starting the cluster costs seconds, so
every module that asks for it shares one: a test must leave it as it found it (cancel or wait for
what it submitted), and may not rely on what earlier tests left on the workers.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest


@pytest.fixture(scope="session")
def dask_cluster() -> Iterator[Any]:
    """A running ``LocalCluster`` (2 worker processes, 1 thread each), closed after the session:
    the one ``activetouch`` starts for ``--workers 2``
    (:func:`app.evaluation.cluster.local_cluster`)."""
    from app.evaluation.cluster import local_cluster

    cluster = local_cluster(2)
    try:
        yield cluster
    finally:
        cluster.close()
