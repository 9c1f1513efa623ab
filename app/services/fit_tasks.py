"""The fits and folds of ``--latent-dim auto`` and the starts of a fit as tasks on Dask
distributed, the engine evaluations run on.

:func:`core.selection.latent_selection.select_latent_dim` hands its independent fits on all the
touches (one per candidate ds) and its warm refits to a map
(:data:`core.selection.latent_selection.WarmMap`), its independent folds without warm refits to
another (:data:`core.selection.latent_selection.FoldMap`), and a fit the first stage of its
independent starts (:data:`core.gp.fit_run.StartMap`: hyperparameters with the latents frozen,
then the screening run). :class:`FitEngine` supplies all three on one client — a ``LocalCluster``
of single-threaded processes started for it, or an existing scheduler
(:func:`app.evaluation.cluster.open_client`): :meth:`FitEngine.warm_map` runs each candidate's
fit on all the touches as one task (:func:`core.selection.nested_fits.fit_rung`, its starts
one after another in the task) and each fold's refit of one candidate as one task that waits
only for the fits it needs (:func:`core.selection.latent_selection.score_warm_fold`: those of
ds up to its candidate's), so refits of small candidates fill the workers while the large ones
are still fitted; :meth:`FitEngine.fold_map` runs all of a fold's nested candidate fits
(:func:`core.selection.latent_selection.score_fold`) as one task, and
:meth:`FitEngine.start_map` each start (:func:`core.gp.fit_run.run_first_stage`). What every task
shares (the :class:`~core.selection.nested_fits.RungPlan`: data and the fit; the
:class:`~core.selection.latent_selection.FoldPlan`: data, folds and the fit; the
:class:`~core.gp.fit_run.StartPlan`: the screening problem and the options) is scattered to
every worker once (``broadcast=True``); a task carries only its ds or fold's index and
generator, or its start's vector, and a warm refit the futures of the fits it needs (Dask
moves each fitted model to a worker at most once). Fits and folds have their own generators and
starts none, so the result is the serial run's whatever worker ran which task. Without warm
folds a fold's candidates depend on each other (ds = k starts from ds = k - 1), so the fold is
the unit of work there. The starts of every fit in a fold's task run as tasks of their own
(:func:`worker_start_map`), so the last folds of a run spread over every worker; the polish of a
fit's best starts runs after its starts, where the fit runs. The candidates' fits of
:meth:`FitEngine.warm_map` do not do that: there the refits fill the workers, and a fit whose
task left its worker's thread pool while its starts ran would come back to polish on the worker
it began on, beside the other fits that began there (docs/fitting.md, "Fits on workers").

Stopping: the ``stop`` callable is polled every :data:`POLL_S` while tasks run; when it raises
(or the caller is interrupted), the pending tasks are cancelled and a local cluster is closed,
which ends the worker processes and the fits running in them. On an existing scheduler a task
already running finishes there and its result is dropped.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from app.evaluation.cluster import open_client
from core.gp import (
    FitOptions,
    NoiseModelChoice,
    StartPlan,
    StartResult,
    StartTask,
    fit_manifold,
    refit_warm,
    run_first_stage,
)
from core.selection import (
    FoldPlan,
    FoldResult,
    FoldTask,
    RungPlan,
    RungResult,
    RungTask,
    fit_rung,
    score_fold,
    score_warm_fold,
)
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray

#: Seconds between two looks at the folds' futures (and at ``stop``) while none has finished.
POLL_S = 0.1

#: Dask priority of a candidate's fit on all the touches: above every refit, whose priority
#: is its candidate's index (the larger candidates' refits, which are ready last and take
#: longest, first).
RUNG_PRIORITY = 1000

#: The same inside a fold's task, for its fits' starts (and the run's stop event).
WORKER_POLL_S = 0.5


@dataclasses.dataclass(frozen=True)
class FoldFit:
    """The fit of one candidate in one fold (:data:`core.selection.nested_fits.StartedFit`),
    picklable so it can be sent to workers.

    Attributes:
        options: Fit options; the nested starts are added as ``initial_latents``.
        noise_model: Noise model of the fold fits.
        starts_as_tasks: Run each fit's starts as tasks of their own on the cluster of the
            fold's task (:func:`worker_start_map`); set by :meth:`FitEngine.fold_map` and
            :meth:`FitEngine.warm_map`.
        stop_event: Name of the Dask ``Event`` set when the run stops: a fold already running
            then submits no more starts and ends (with ``starts_as_tasks``).
    """

    options: FitOptions
    noise_model: NoiseModelChoice
    starts_as_tasks: bool = False
    stop_event: str | None = None

    def __call__(
        self,
        train: TrainingData,
        latent_dim: int,
        starts: tuple[FloatArray, ...],
        rng: np.random.Generator,
    ) -> ManifoldModel:
        started = dataclasses.replace(self.options, initial_latents=starts)
        return fit_manifold(
            train,
            latent_dim,
            rng,
            started,
            noise_model=self.noise_model,
            start_map=functools.partial(worker_start_map, stop_event=self.stop_event)
            if self.starts_as_tasks
            else None,
        )

    def refit(self, train: TrainingData, model: ManifoldModel) -> ManifoldModel:
        """A warm fold's model: ``model`` refitted to ``train`` from where it stands
        (:data:`core.selection.latent_selection.WarmRefit`, :func:`core.gp.refit_warm` with
        these options)."""
        return refit_warm(train, model, self.options)


class RunStoppedError(Exception):
    """The run a fold belongs to was stopped (its ``stop_event`` is set)."""


def worker_start_map(
    plan: StartPlan, tasks: Sequence[StartTask], stop_event: str | None = None
) -> Iterator[StartResult]:
    """A :data:`core.gp.fit_run.StartMap` for a fit that runs inside a Dask task (a fold): its
    starts become tasks on the same cluster. The fold's task leaves its worker's thread pool
    while they run (``worker_client`` secedes), so an idle worker takes some of them — the last
    folds of a run then use every worker — and rejoins it for the polish.

    Raises:
        RunStoppedError: The Dask ``Event`` named ``stop_event`` is set (the run was stopped;
            a running task cannot be cancelled, so it ends itself here).
    """
    from distributed import Event, worker_client

    with worker_client() as client:
        event = None if stop_event is None else Event(stop_event, client=client)
        prefix = uuid.uuid4().hex[:8]
        [remote] = client.scatter([plan], hash=False)
        futures = [
            client.submit(
                run_first_stage, remote, task, pure=False, key=f"start-{task.index}-{prefix}"
            )
            for task in tasks
        ]
        pending = set(futures)
        try:
            while pending:
                done = {future for future in pending if future.done()}
                pending -= done
                for future in done:
                    yield future.result()
                if not done:
                    if event is not None and event.is_set():
                        raise RunStoppedError(f"the run was stopped ({stop_event}).")
                    time.sleep(WORKER_POLL_S)
        finally:
            if pending:
                client.cancel(list(pending))
            # The worker keeps a stopped fold's error with its traceback, and so this frame:
            # release the plan and the starts here, not when the frame goes.
            for future in (remote, *futures):
                future.release()


class FitEngine:
    """Folds and starts as Dask tasks on one client (module docstring); a context manager.

    Args:
        workers: Size of a ``LocalCluster`` started for the engine (when ``scheduler`` is None).
        scheduler: Address of an existing Dask scheduler, ``tcp://host:8786``.
        stop: Called between polls; it raises to stop the run (e.g. ``Job.checkpoint``).

    Raises:
        ValueError: Neither a scheduler nor at least one worker.
        BadInputError: (on entry) the scheduler cannot be reached or has no worker.
    """

    def __init__(
        self,
        workers: int | None,
        scheduler: str | None,
        stop: Callable[[], None] | None = None,
    ) -> None:
        if scheduler is None and (workers is None or workers < 1):
            raise ValueError(f"workers: need at least 1 without a scheduler, received {workers!r}.")
        self.workers = workers
        self.scheduler = scheduler
        self.stop = stop
        self._stack: contextlib.ExitStack | None = None
        self._client: Any = None

    def __enter__(self) -> FitEngine:
        stack = contextlib.ExitStack()
        self._client = stack.enter_context(open_client(self.workers, self.scheduler))
        self._stack = stack
        return self

    def __exit__(self, *exc: object) -> None:
        if self._stack is not None:
            self._stack.close()
        self._stack, self._client = None, None

    def fold_map(self, plan: FoldPlan, tasks: Sequence[FoldTask]) -> Iterator[FoldResult]:
        """A :data:`core.selection.latent_selection.FoldMap`: every task as one Dask task — a
        fold, or with warm folds a fold's candidate — (and the starts of its fits as tasks of
        their own when the fit is a :class:`FoldFit`)."""
        stop_event = None
        if isinstance(plan.fit, FoldFit):
            stop_event = f"stop-{uuid.uuid4().hex[:8]}"
            fit = _on_workers(plan.fit, stop_event)
            refit = None if plan.refit is None else fit.refit
            plan = dataclasses.replace(plan, fit=fit, refit=refit)
        names = [
            f"fold-{t.fold}" if t.rows is None else f"fold-{t.fold}-{'-'.join(map(str, t.rows))}"
            for t in tasks
        ]
        return self._run(score_fold, plan, list(zip(names, tasks, strict=True)), stop_event)

    def warm_map(
        self,
        rung_plan: RungPlan,
        rungs: Sequence[RungTask],
        fold_plan: FoldPlan,
        folds: Sequence[FoldTask],
    ) -> Iterator[RungResult | FoldResult]:
        """A :data:`core.selection.latent_selection.WarmMap`: every candidate's fit on all the
        touches as one task (its starts in the task), and every fold's refit of a
        candidate as one task that depends on the fits of ds up to its candidate's
        (:func:`core.selection.latent_selection.score_warm_fold`), so Dask starts it as soon
        as those are done, while the larger candidates are still being fitted."""
        stop_event = f"stop-{uuid.uuid4().hex[:8]}"
        if isinstance(rung_plan.fit, FoldFit):
            whole = _on_workers(rung_plan.fit, stop_event, starts_as_tasks=False)
            rung_plan = dataclasses.replace(rung_plan, fit=whole)
        if isinstance(fold_plan.fit, FoldFit):
            fit = _on_workers(fold_plan.fit, stop_event)
            refit = None if fold_plan.refit is None else fit.refit
            fold_plan = dataclasses.replace(fold_plan, fit=fit, refit=refit)
        dims = list(fold_plan.dims)

        def submit(client: Any, prefix: str) -> set[Any]:
            rung_remote, fold_remote = client.scatter(
                [rung_plan, fold_plan], broadcast=True, hash=False
            )
            fitted = {
                task.latent_dim: client.submit(
                    fit_rung,
                    rung_remote,
                    task,
                    pure=False,
                    key=f"rung-{task.latent_dim}-{prefix}",
                    priority=RUNG_PRIORITY,
                )
                for task in rungs
            }
            refits = set()
            for task in folds:
                if task.rows is None or len(task.rows) != 1:
                    raise ValueError("warm_map: a warm fold task scores exactly one candidate.")
                (c,) = task.rows
                needed = [fitted[ds] for ds in dims[: c + 1]]
                refits.add(
                    client.submit(
                        _score_warm_fold,
                        fold_remote,
                        task,
                        *needed,
                        pure=False,
                        key=f"fold-{task.fold}-{c}-{prefix}",
                        priority=c,
                    )
                )
            return set(fitted.values()) | refits

        return self._collect(submit, stop_event)

    def start_map(self, plan: StartPlan, tasks: Sequence[StartTask]) -> Iterator[StartResult]:
        """A :data:`core.gp.fit_run.StartMap`: every start's first stage as one task, on one
        thread (a worker is one thread of the cluster)."""
        tasks_ = [(f"start-{t.index}", t) for t in tasks]
        return self._run(run_first_stage, plan.on_one_thread(), tasks_)

    def _run(
        self,
        function: Callable[[Any, Any], Any],
        shared: Any,
        tasks: list[tuple[str, Any]],
        stop_event: str | None = None,
    ) -> Iterator[Any]:
        """``function(shared, task)`` of every task as Dask tasks, ``shared`` scattered once;
        the results in the order they finish (:meth:`_collect`)."""

        def submit(client: Any, prefix: str) -> set[Any]:
            [remote] = client.scatter([shared], broadcast=True, hash=False)
            return {
                client.submit(function, remote, task, pure=False, key=f"{name}-{prefix}")
                for name, task in tasks
            }

        return self._collect(submit, stop_event)

    def _collect(
        self, submit: Callable[[Any, str], set[Any]], stop_event: str | None = None
    ) -> Iterator[Any]:
        """The results of the futures ``submit(client, key prefix)`` returns, in the order they
        finish. Stopped early, the pending futures are cancelled and the Dask ``Event``
        ``stop_event`` (if any) is set for the running ones."""
        if self._client is None:
            raise RuntimeError("FitEngine: use it in a `with` block.")
        client = self._client
        pending: set[Any] = set()
        try:
            pending = submit(client, uuid.uuid4().hex[:8])
            while pending:
                done = {future for future in pending if future.done()}
                if not done:
                    time.sleep(POLL_S)
                pending -= done
                for future in done:
                    yield future.result()
                if self.stop is not None:
                    self.stop()
        finally:
            if pending:
                if stop_event is not None:
                    from distributed import Event

                    Event(stop_event, client=client).set()
                client.cancel(list(pending))


def _score_warm_fold(plan: FoldPlan, task: FoldTask, *rungs: RungResult) -> FoldResult:
    """:func:`core.selection.latent_selection.score_warm_fold` with the rungs as positional
    arguments (Dask passes the results of the futures it depends on that way)."""
    return score_warm_fold(plan, task, rungs)


def _on_workers(fit: FoldFit, stop_event: str, starts_as_tasks: bool = True) -> FoldFit:
    """The fit as a worker runs it: on one thread (a worker is one thread of the cluster), its
    starts as tasks of their own (unless ``starts_as_tasks`` is false: then one after another
    in the fit's task), ending when ``stop_event`` is set."""
    options = dataclasses.replace(fit.options, threads=1)
    return dataclasses.replace(
        fit, options=options, starts_as_tasks=starts_as_tasks, stop_event=stop_event
    )
