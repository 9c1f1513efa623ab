"""Trials as tasks on Dask distributed: a ``LocalCluster`` of single-threaded processes, or an
existing scheduler.

The :class:`~app.evaluation.context.TrialContext` (model, spec, replay pools) is scattered to
every worker once (``broadcast=True``); a task carries only the keys (policy, target, index) of a
batch of trials (up to :data:`MAX_BATCH`, at least :data:`TASKS_PER_WORKER` tasks per worker) and
a reference to that context, and returns their :class:`~core.evaluation.records.TrialRecord`
(or :class:`~core.evaluation.records.RefusedTrial`).
Planners and their candidate statistics are built once per worker process, on its first trial.
At most a few tasks per worker are queued at a time, so a stop cancels little and results come
back as they finish.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from app.errors import BadInputError
from app.evaluation.context import TrialContext, TrialKey, run_trials_task
from core.evaluation import TrialOutcome

#: Environment of every worker process: BLAS on one thread (the worker's one core).
WORKER_ENVIRONMENT = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

#: glibc's allocator in every worker, set before the process starts (Dask's
#: ``distributed.nanny.pre-spawn-environ``). Dask sets ``MALLOC_TRIM_THRESHOLD_`` = 64 KiB
#: there, which also freezes glibc's mmap threshold at 128 KiB: every N x N array of a fit
#: (5 MB at N = 800) was then a fresh mmap, faulted in page by page and unmapped on release —
#: 25 million page faults and 105-110 s of system time per worker in one ``--latent-dim
#: auto`` run on 800 touches (docs/fitting.md, "Fits on workers"). Arrays up to 32 MiB (the
#: most glibc allows) now come from the heap and are reused, and up to 256 MiB of freed heap
#: stays with the process.
WORKER_ALLOCATOR = {
    "MALLOC_MMAP_THRESHOLD_": str(32 << 20),
    "MALLOC_TRIM_THRESHOLD_": str(256 << 20),
}

#: How long to wait for an existing scheduler (and for it to have a worker).
CONNECT_TIMEOUT_S = 5.0

#: Tasks queued per worker beyond the one it runs.
QUEUE_PER_WORKER = 2

#: Most trials in one task.
MAX_BATCH = 16

#: Fewest tasks per worker when the trials are split into batches.
TASKS_PER_WORKER = 4


def local_cluster(workers: int) -> Any:
    """A ``LocalCluster`` of ``workers`` single-threaded worker processes, BLAS on one thread
    and glibc's allocator keeping large arrays on the heap (:data:`WORKER_ALLOCATOR`)."""
    import dask.config
    from distributed import LocalCluster

    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ"), **WORKER_ALLOCATOR}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": pre_spawn}):
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            silence_logs=logging.ERROR,
            env=WORKER_ENVIRONMENT,
        )


def probe(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Open and close one Dask connection to ``address`` (a handshake), in a thread of its own.

    Done before a ``Client`` exists: a client whose start fails is left half-built and its
    clean-up blocks for seconds more at exit.

    Raises:
        BadInputError: Not an address, nothing answers, or what answers is not Dask, within
            ``timeout_s``.
    """
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect as open_comm

    async def handshake() -> None:
        comm = await open_comm(address, timeout=timeout_s)
        await comm.close()

    def run() -> None:
        asyncio.run(asyncio.wait_for(handshake(), timeout_s + 1.0))

    with ThreadPoolExecutor(max_workers=1) as pool:
        try:
            pool.submit(run).result()
        except (OSError, TimeoutError, ValueError) as exc:
            raise BadInputError(
                f"scheduler: cannot reach a Dask scheduler at {address!r} within "
                f"{timeout_s:g} s ({type(exc).__name__}: {exc}).",
                field="scheduler",
            ) from None
        except Exception as exc:  # a garbled handshake: whatever answers does not speak Dask
            raise BadInputError(
                f"scheduler: something answers at {address!r} but it is not a Dask scheduler "
                f"(its handshake failed: {type(exc).__name__}).",
                field="scheduler",
            ) from None


def connect(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Any:
    """A client of an existing scheduler that has at least one worker.

    Raises:
        BadInputError: The scheduler cannot be reached, or has no worker, within ``timeout_s``.
    """
    from distributed import Client

    probe(address, timeout_s)
    try:
        client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except Exception as exc:
        raise BadInputError(
            f"scheduler: cannot reach a Dask scheduler at {address!r} within "
            f"{timeout_s:g} s ({type(exc).__name__}: {exc}).",
            field="scheduler",
        ) from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        client.close()
        raise BadInputError(
            f"scheduler: the Dask scheduler at {address!r} has no worker "
            f"(waited {timeout_s:g} s: {exc}); start one with `dask worker {address} "
            "--nthreads 1`.",
            field="scheduler",
        ) from None
    return client


@contextmanager
def open_client(workers: int | None, scheduler: str | None) -> Iterator[Any]:
    """A client of the scheduler at ``scheduler``, or of a :func:`local_cluster` of ``workers``
    processes started for it; on exit the client, and the local cluster, are closed (which
    ends its worker processes and whatever ran there).

    Raises:
        BadInputError: The scheduler cannot be reached or has no worker.
        ValueError: Neither a scheduler nor at least one worker.
    """
    from distributed import Client

    cluster = None
    if scheduler is not None:
        client = connect(scheduler)
    else:
        if workers is None or workers < 1:
            raise ValueError(f"workers: need at least 1 without a scheduler, received {workers!r}.")
        cluster = local_cluster(workers)
        client = Client(cluster, set_as_default=False)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def batches(keys: list[TrialKey], n_workers: int) -> list[list[TrialKey]]:
    """Split the trials into tasks of up to :data:`MAX_BATCH` trials, ≥ 4 tasks per worker.

    A task of several trials pays the scheduler's round trip once for all of them; small runs
    keep one trial per task so every worker gets work.
    """
    size = max(1, min(MAX_BATCH, len(keys) // (TASKS_PER_WORKER * n_workers)))
    return [keys[i : i + size] for i in range(0, len(keys), size)]


def run_on_cluster(
    context: TrialContext,
    keys: list[TrialKey],
    collect: Callable[[TrialOutcome], None],
    stop: Callable[[], bool],
    workers: int | None,
    scheduler: str | None,
) -> tuple[bool, int]:
    """Run ``keys`` as tasks; ``collect`` each record in this thread as its task finishes.

    Returns:
        (stopped, number of workers).

    Raises:
        BadInputError: The scheduler cannot be reached or has no worker.
    """
    from distributed import as_completed

    with open_client(workers, scheduler) as client:
        n_workers = max(1, len(client.scheduler_info(n_workers=-1)["workers"]))
        [shared] = client.scatter([context], broadcast=True, hash=False)
        pending = iter(batches(keys, n_workers))
        window = n_workers * (1 + QUEUE_PER_WORKER)

        def submit(batch: list[TrialKey]) -> Any:
            policy, target, trial = batch[0]
            name = f"trials-{policy}-{target}-{trial}-{len(batch)}"
            return client.submit(run_trials_task, shared, batch, pure=False, key=name)

        first = [submit(b) for _, b in zip(range(window), pending, strict=False)]
        # Results are fetched in the background as tasks finish (with_results), not one round
        # trip at a time from this thread.
        futures = as_completed(first, with_results=True, loop=client.loop)
        stopped = False
        for _, records in futures:
            for record in records:
                collect(record)
            if stop():
                stopped = True
                break
            following = next(pending, None)
            if following is not None:
                futures.add(submit(following))
        if stopped:
            futures.clear()
        return stopped, n_workers
