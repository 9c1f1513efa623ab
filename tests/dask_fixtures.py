"""A Dask ``LocalCluster`` for tests: 2 single-threaded worker processes, started once per session.

Registered from ``tests/conftest.py`` (``pytest_plugins``). Starting the cluster costs seconds, so
every module that asks for it shares one: a test must leave it as it found it (cancel or wait for
what it submitted), and may not rely on what earlier tests left on the workers.
"""

from __future__ import annotations

import time
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


def keys_left(address: str, prefixes: tuple[str, ...], within_s: float = 30.0) -> list[str]:
    """The keys on the scheduler at ``address`` that start with one of ``prefixes``, once there
    are none or ``within_s`` seconds have passed: a stopped run's tasks already running end at
    their next look at the run's stop event, and the scheduler forgets them then."""
    from distributed import Client

    deadline = time.monotonic() + within_s
    with Client(address, set_as_default=False) as client:
        while True:
            left = [
                key
                for key in client.run_on_scheduler(
                    lambda dask_scheduler: [str(k) for k in dask_scheduler.tasks]
                )
                if key.startswith(prefixes)
            ]
            if not left or time.monotonic() > deadline:
                return left
            time.sleep(0.2)
