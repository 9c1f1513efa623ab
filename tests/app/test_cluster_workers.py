"""The workers of the ``LocalCluster`` the app starts keep large arrays on the heap."""

from __future__ import annotations

from typing import Any

from app.evaluation.cluster import WORKER_ALLOCATOR, WORKER_ENVIRONMENT


def _allocate_and_count_faults() -> tuple[int, dict[str, str | None]]:
    """Minor page faults of 40 allocations of a 5 MB array (an 800 x 800 Gram matrix), each
    written in full and released, and the allocator's environment in the worker."""
    import os
    import resource

    import numpy as np

    np.ones((800, 800)).sum()  # let the heap grow once
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(40):
        np.ones((800, 800)).sum()
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    names = [*WORKER_ALLOCATOR, *WORKER_ENVIRONMENT]
    return faults, {name: os.environ.get(name) for name in names}


def test_workers_reuse_large_arrays_instead_of_faulting_them_in(dask_cluster: Any) -> None:
    from distributed import Client

    with Client(dask_cluster) as client:
        results = client.run(_allocate_and_count_faults)
    assert len(results) == 2
    pages = 40 * 800 * 800 * 8 // 4096  # what fresh mappings would fault in: 50,000 pages
    for faults, environment in results.values():
        assert environment == {**WORKER_ALLOCATOR, **WORKER_ENVIRONMENT}
        assert faults < pages // 20, f"{faults} page faults for 40 reused 5 MB arrays"
