"""Project-wide pytest options (pytest only reads ``pytest_addoption`` here, at the root).

``--turntable-port``, ``--finger-port``, ``--tactile-port``: serial ports of real devices; the
``*_with_device.py`` tests are skipped unless the port they need is given.

The suite runs on two pytest-xdist workers (``scripts/test.sh``: ``-n 2 --dist loadgroup``); the
browser tests share one demo and the Dask tests one cluster, so each of those kinds stays on one
worker (:func:`pytest_collection_modifyitems`). Schemathesis' API tests, generated at run time,
run on their own after (under xdist only the first would run).
"""

from __future__ import annotations

import os

# Small dense problems: BLAS threads only thrash on 2 shared cores (set before numpy loads).
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import pytest  # noqa: E402

pytest_plugins = ["tests.dask_fixtures", "pytester"]

SETTLE_S = 5.0
"""Rest before each touch of the simulated rigs that tests drive through a server (the default is
20 s). One recovery time of the simulated skin (4 s) keeps the touches alike at a quarter of the
cost: the rest is simulated, sample by sample. tests/hardware/test_settle.py tests the rest."""


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("activetouch hardware", "tests against real devices")
    group.addoption("--turntable-port", default=None, help="GRBL turntable port (115200 baud)")
    group.addoption("--finger-port", default=None, help="Dynamixel bus port (1 Mbaud)")
    group.addoption("--tactile-port", default=None, help="tactile sensor port (460800 baud)")


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Keep the tests that share a session fixture on one xdist worker: the browser tests (one
    demo, prepared in a minute) and the tests on the Dask cluster (one ``LocalCluster``)."""
    for item in items:
        if item.get_closest_marker("browser") is not None:
            item.add_marker(pytest.mark.xdist_group("browser"))
        elif "dask_cluster" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("dask"))
