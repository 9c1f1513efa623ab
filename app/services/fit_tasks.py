"""The folds of ``--latent-dim auto`` as tasks on Dask distributed, the engine evaluations run on.

:func:`core.selection.latent_selection.select_latent_dim` hands its independent folds to a ``map``
(:data:`core.selection.latent_selection.FoldMap`); :func:`dask_fold_map` is one that runs each fold
— all its nested candidate fits, :func:`core.selection.latent_selection.score_fold` — as one task,
on a ``LocalCluster`` of single-threaded processes or an existing scheduler
(:mod:`app.evaluation.cluster`). The :class:`~core.selection.latent_selection.FoldPlan` (data,
folds, the fit) is scattered to every worker once (``broadcast=True``); a task carries only its
fold's index and generator. Each fold has its own generator, so the result is the serial run's
whatever worker ran which fold. A fold's candidates depend on each other (ds = k starts from
ds = k - 1), so the fold is the unit of work; the final fit on all the data runs afterwards, in
process.

Stopping: the ``stop`` callable is polled every :data:`POLL_S` while tasks run; when it raises
(or the caller is interrupted), the pending tasks are cancelled and a local cluster is closed,
which ends the worker processes and the fits running in them. On an existing scheduler a fold
already running finishes there and its result is dropped.
"""

from __future__ import annotations

import dataclasses
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from app.evaluation.cluster import connect, local_cluster
from core.gp import FitOptions, NoiseModelChoice, fit_manifold
from core.selection import FoldMap, FoldPlan, FoldResult, FoldTask, score_fold
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray

#: Seconds between two looks at the folds' futures (and at ``stop``) while none has finished.
POLL_S = 0.1


@dataclasses.dataclass(frozen=True)
class FoldFit:
    """The fit of one candidate in one fold (:data:`core.selection.nested_fits.StartedFit`),
    picklable so it can be sent to workers.

    Attributes:
        options: Fit options; the nested starts are added as ``initial_latents``.
        noise_model: Noise model of the fold fits.
    """

    options: FitOptions
    noise_model: NoiseModelChoice

    def __call__(
        self,
        train: TrainingData,
        latent_dim: int,
        starts: tuple[FloatArray, ...],
        rng: np.random.Generator,
    ) -> ManifoldModel:
        started = dataclasses.replace(self.options, initial_latents=starts)
        return fit_manifold(train, latent_dim, rng, started, noise_model=self.noise_model)


def dask_fold_map(
    workers: int | None,
    scheduler: str | None,
    stop: Callable[[], None] | None = None,
) -> FoldMap:
    """A fold map that runs every fold as a Dask task (module docstring).

    Args:
        workers: Size of a ``LocalCluster`` started for the run (when ``scheduler`` is None).
        scheduler: Address of an existing Dask scheduler, ``tcp://host:8786``.
        stop: Called between polls; it raises to stop the run (e.g. ``Job.checkpoint``).

    Returns:
        The map; it yields the folds' results as they finish.

    Raises:
        BadInputError: (when the map runs) the scheduler cannot be reached or has no worker.
    """
    if scheduler is None and (workers is None or workers < 1):
        raise ValueError(f"workers: need at least 1 without a scheduler, received {workers!r}.")

    def run(plan: FoldPlan, tasks: Sequence[FoldTask]) -> Iterator[FoldResult]:
        from distributed import Client

        cluster = None
        if scheduler is not None:
            client = connect(scheduler)
        else:
            assert workers is not None
            cluster = local_cluster(workers)
            client = Client(cluster, set_as_default=False)
        pending: set[Any] = set()
        try:
            [shared] = client.scatter([plan], broadcast=True, hash=False)
            prefix = f"fold-{uuid.uuid4().hex[:8]}"
            pending = {
                client.submit(score_fold, shared, task, pure=False, key=f"{prefix}-{task.fold}")
                for task in tasks
            }
            while pending:
                done = {future for future in pending if future.done()}
                if not done:
                    time.sleep(POLL_S)
                pending -= done
                for future in done:
                    yield future.result()
                if stop is not None:
                    stop()
        finally:
            if pending:
                client.cancel(list(pending))
            client.close()
            if cluster is not None:
                cluster.close()

    return run
