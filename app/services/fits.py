"""Fits: a model is fitted to a dataset as a job of the job runner (:mod:`app.services.jobs`).

``POST /models`` stores the model ``queued`` and hands :func:`run_fit` to the runner, which runs
at most the server's ``max_concurrent_fits`` fits at once; the others wait ``queued`` with their
place in the queue (``queue_position``). A fit is ``fitting`` while it runs, then ``ready`` (the
fitted model stored, :func:`app.services.models.store_fitted`), ``failed`` (with the reason) or
``stopped`` (``POST /models/{id}/stop``: a queued fit never starts, a running one ends at its
next progress checkpoint). Progress is written to the row and announced as ``model.progress``
(at most every :data:`PROGRESS_INTERVAL_S`), with the stage running (``latent selection`` or
``fit``), its fraction done and its estimated seconds left (``remaining_s``,
:mod:`app.services.remaining`); state changes as ``model.status``.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from sqlalchemy.orm import Session

from app import crud, states
from app.config import available_cores
from app.db import Database
from app.db.tables import utc_now
from app.documents.model import latent_selection_dict
from app.errors import BadInputError, ConflictError
from app.rig.action_layout import shift_dimensions
from app.schemas import ModelAccepted, ModelCreate, ModelPublic
from app.services import datasets
from app.services.events import EventBus
from app.services.fit_tasks import FitEngine, FoldFit
from app.services.jobs import INTERRUPTED, Job, JobCancelled, JobRunner
from app.services.models import ReadyModels, require, store_fitted, to_public
from app.services.remaining import RemainingTime, stage_of
from core.errors import CoreError, InvalidInputError
from core.features.pipeline import check_touches, fit_features
from core.features.raw import RawTouch
from core.gp import (
    FitCancelledError,
    FitOptions,
    FitProgress,
    NoiseModelChoice,
    fit_manifold,
    fit_structure,
    iter_fit,
    refit_warm,
)
from core.recognition import calibrate
from core.selection import (
    DEFAULT_FOLDS,
    DEFAULT_MAX_LATENT_DIM,
    RUNG_COST_IN_REFITS,
    LatentSelection,
    select_latent_dim,
)
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray

logger = logging.getLogger(__name__)

KIND: Literal["fit"] = "fit"

#: Seconds between two progress events (and progress writes) of one fit.
PROGRESS_INTERVAL_S = 0.25


@dataclasses.dataclass(frozen=True)
class FitRequest:
    """What one fit job needs: the model's row id, its training data, the request, the server's
    Dask scheduler (``None``: none configured) and, when the request asks for ``features``, the
    dataset's raw touches (y is then made of them by the pipeline the job fits)."""

    model_id: int
    data: TrainingData
    body: ModelCreate
    scheduler: str | None = None
    touches: tuple[RawTouch, ...] | None = None


class FitService:
    """Starts, stops and records the fits of models.

    Args:
        database: Where models live.
        events: Where progress and state changes are announced.
        jobs: The job runner the fits run on (its ``fit`` limit: fits at once).
        models: Keeps each fitted model for use.
        max_training_touches: Largest N accepted for a fit.
        scheduler: Address of the Dask scheduler the folds of ``latent_dim: "auto"`` run on
            (``ACTIVETOUCH_DASK_SCHEDULER``); without one they run on the request's ``workers``
            local processes, or in process when it gives none.
    """

    def __init__(
        self,
        database: Database,
        events: EventBus,
        jobs: JobRunner,
        models: ReadyModels,
        max_training_touches: int = 5000,
        scheduler: str | None = None,
    ) -> None:
        self._scheduler = scheduler
        self._database = database
        self._events = events
        self._jobs = jobs
        self._models = models
        self._max_touches = max_training_touches

    def submit(self, session: Session, body: ModelCreate) -> ModelAccepted:
        """Check the request, store the model (``queued``) and hand its fit to the runner.

        Raises:
            NotFoundError: (404) no such dataset.
            BadInputError: (422) too many touches, or ``auto`` with too few touches per object.
            ConflictError: (409) the server is shutting down.
        """
        data = datasets.load_training_data(session, body.dataset_id)
        self._models.check_size(data.n_touches, "dataset_id")
        fit_structure(data, "auto", body.kernels)  # tied kernels: dense only (422 otherwise)
        touches = None if body.features is None else self._raw_touches(session, body)
        fewest = int(data.touches_per_object().min())
        if body.latent_dim == "auto" and fewest < 4:
            raise BadInputError(
                f"latent_dim: 'auto' cross-validates over touches within objects and needs at "
                f"least 4 touches of every object; this dataset has an object with {fewest}.",
                field="latent_dim",
            )
        self._jobs.check_open()
        row = crud.create_model(
            session,
            dataset_id=body.dataset_id,
            status="queued",
            latent_dim=0 if body.latent_dim == "auto" else body.latent_dim,
            optimizer=body.optimizer,
            restarts=body.restarts,
            seed=body.seed,
        )
        session.commit()
        model_id = row.id
        self._announce(model_id, "queued", dataset_id=row.dataset_id)
        request = FitRequest(model_id, data, body, self._scheduler, touches)
        job = self._jobs.start(KIND, model_id, lambda job: self._run(job, request))
        if not job.waiting:  # started at once: fitting from now on
            self._set_fitting(model_id)
        session.refresh(row)
        position = self.queue_position(model_id)
        return ModelAccepted(id=model_id, status=row.status, queue_position=position)

    @staticmethod
    def _raw_touches(session: Session, body: ModelCreate) -> tuple[RawTouch, ...]:
        """The dataset's raw touches for ``body.features``, checked as the pipeline needs them.

        Raises:
            BadInputError: (422, field ``features``) a sample without raw series, touches of
                different channel sets or a series shorter than the pipeline's window (the
                sample and channel named); ``feature_dim`` given with ``features: "means"``.
        """
        assert body.features is not None
        if body.features == "means" and body.feature_dim != "auto":
            raise BadInputError(
                "feature_dim: only features 'whole' is projected to dy; 'means' gives one "
                "feature per channel element.",
                field="feature_dim",
            )
        _, touches = datasets.raw_touches(session, body.dataset_id)
        try:
            check_touches(touches, body.features)
        except InvalidInputError as exc:
            sample = str(exc).replace("touch ", "sample ", 1)
            raise BadInputError(
                f"features: dataset {body.dataset_id}, {sample}", field="features"
            ) from None
        return tuple(touches)

    def queue_position(self, model_id: int) -> int | None:
        """The model's place in the queue of fits (1: next to start), if it is waiting."""
        return self._jobs.queue_position(KIND, model_id)

    def get(self, session: Session, model_id: int) -> ModelPublic:
        """One model, with its place in the queue of fits."""
        return to_public(require(session, model_id), self.queue_position(model_id))

    def stop(self, session: Session, model_id: int) -> ModelPublic:
        """Stop a queued or running fit: it ends ``stopped`` (a running one at its next progress
        checkpoint).

        Raises:
            NotFoundError: (404) no such model.
            ConflictError: (409) the fit has ended (``current_state`` says how).
        """
        with self._jobs.run_lock(KIND, model_id):
            row = require(session, model_id)
            if row.status not in states.MODEL_ACTIVE:
                raise ConflictError(
                    f"Cannot stop the fit of model {model_id}: it is {row.status} (stop is "
                    f"allowed from: {', '.join(states.MODEL_ACTIVE)}).",
                    current_state=row.status,
                )
            row.status = "stopped"
            row.reason = "stop requested"
            row.finished_at = utc_now()
            session.commit()
            job = self._jobs.handle(KIND, model_id)
            if job is not None:
                job.request_stop("stopped")
        self._announce(model_id, "stopped", reason=row.reason)
        return to_public(row, None)

    # --- the job ------------------------------------------------------------------------------

    def _run(self, job: Job, request: FitRequest) -> None:
        """The fit job: ``queued → fitting``, then :func:`run_fit`, then the model's end."""
        model_id = request.model_id
        try:
            job.checkpoint()
            if not self._set_fitting(model_id):
                return
            report = functools.partial(self._report, model_id, RemainingTime())
            fitted, selection, fit_seconds = run_fit(request, job, report)
        except JobCancelled as cancelled:
            if cancelled.kind == "shutdown":
                self._end(model_id, "failed", INTERRUPTED)
            else:  # already stopped by the request
                self._end(model_id, "stopped", "stop requested")
            return
        except (CoreError, ValueError, ArithmeticError) as exc:
            self._end(model_id, "failed", f"{type(exc).__name__}: {exc}")
            return
        except Exception as exc:  # a bug must still leave the model failed, not "fitting"
            logger.exception("fit of model %d failed", model_id)
            self._end(model_id, "failed", f"internal error: {type(exc).__name__}: {exc}")
            return
        with self._jobs.run_lock(KIND, model_id), self._database.session() as session:
            row = require(session, model_id)
            if row.status != "fitting":  # stopped as it finished
                return
            store_fitted(
                row, fitted, fit_seconds, selection, featurised=request.touches is not None
            )
            session.commit()
        self._models.remember(model_id, fitted)
        self._events.publish(
            "model.status",
            {
                "model_id": model_id,
                "status": "ready",
                "log_likelihood": float(fitted.log_likelihood),
                "fit_seconds": fit_seconds,
            },
        )

    def _set_fitting(self, model_id: int) -> bool:
        """``queued → fitting`` (once: by the request when the fit starts at once, else by the
        job); false when it was stopped before it started."""
        with self._jobs.run_lock(KIND, model_id), self._database.session() as session:
            row = require(session, model_id)
            if row.status == "fitting":
                return True
            if row.status != "queued":
                return False
            row.status = "fitting"
            session.commit()
        self._announce(model_id, "fitting")
        return True

    def _report(
        self, model_id: int, remaining: RemainingTime, progress: FitProgress, elapsed_s: float
    ) -> None:
        """Write and announce one progress event, with the time the running stage has left
        (:mod:`app.services.remaining`)."""
        stage = stage_of(progress.phase)
        remaining_s = remaining.update(stage, progress.fraction, elapsed_s)
        values = {
            "start": int(progress.start),
            "n_starts": int(progress.n_starts),
            "iteration": int(progress.iteration),
            "phase": str(getattr(progress, "phase", "")),
            "log_likelihood": _finite_or_none(progress.log_likelihood),
            "best_log_likelihood": _finite_or_none(progress.best_log_likelihood),
            "elapsed_s": elapsed_s,
            "stage": stage,
            "fraction": _finite_or_none(progress.fraction),
            "remaining_s": remaining_s,
        }
        with self._database.session() as session:
            row = require(session, model_id)
            row.progress = values
            session.commit()
        self._events.publish("model.progress", {"model_id": model_id, **values})

    def _end(self, model_id: int, status: str, reason: str) -> None:
        """End a fit that is still queued or fitting (a stop request may have ended it)."""
        with self._jobs.run_lock(KIND, model_id), self._database.session() as session:
            row = require(session, model_id)
            if row.status not in states.MODEL_ACTIVE:
                return
            row.status = status
            row.reason = reason
            row.finished_at = utc_now()
            session.commit()
        self._announce(model_id, status, reason=reason)

    def _announce(self, model_id: int, status: str, **data: Any) -> None:
        self._events.publish("model.status", {"model_id": model_id, "status": status, **data})


def run_fit(
    request: FitRequest,
    job: Job,
    report: Callable[[FitProgress, float], None],
) -> tuple[ManifoldModel, dict[str, Any] | None, float]:
    """The body of a fit job: fit the feature pipeline if asked (y from the raw touches), choose
    ds if asked (cross-validation), fit the model, then estimate σ_b² from the training
    touches' placements when the dataset records them (:func:`core.gp.with_placement_effect`,
    as ``activetouch fit`` does).

    Args:
        request: The model's id, its training data and the request.
        job: The job; :meth:`~app.services.jobs.Job.checkpoint` is passed at every progress
            event, so a stop ends the fit there.
        report: Receives progress (``FitProgress``, seconds since the fit started), at most
            every :data:`PROGRESS_INTERVAL_S` and for the last event.

    Returns:
        The fitted model, the record of the ds selection (``None`` for a fixed ds) and the
        wall time of the fit in seconds.

    Raises:
        JobCancelled: The job was stopped or the server is shutting down.
        CoreError, ValueError, ArithmeticError: The fit failed.
    """
    body, data = request.body, request.data
    options_kwargs: dict[str, Any] = {
        "optimizer": body.optimizer,
        "kernels": body.kernels,
        "restarts": body.restarts,
        "threads": available_cores(),  # feature threads here; 1 in a Dask worker (fit_tasks)
    }
    if body.max_iterations is not None:
        options_kwargs["max_iterations"] = body.max_iterations
    options = FitOptions(**options_kwargs)
    rng = np.random.default_rng(body.seed)
    started = time.perf_counter()
    pipeline = None
    if request.touches is not None and body.features is not None:
        job.checkpoint()
        pipeline = fit_features(
            request.touches,
            data.object_index,
            body.features,
            feature_dim=None if body.feature_dim == "auto" else body.feature_dim,
            seed=body.seed or 0,
        )
        data = dataclasses.replace(data, observations=pipeline.transform_many(request.touches))
        request = dataclasses.replace(request, data=data)
    selection: dict[str, Any] | None = None
    latent_dim = body.latent_dim
    done_before: ManifoldModel | None = None
    if latent_dim == "auto":
        chosen = _select_latent_dim(data, request, options, rng, job, report, started)
        selection = latent_selection_dict(chosen)
        latent_dim = chosen.chosen
        done_before = chosen.chosen_model  # the fit on all the data at that ds
    fitted: ManifoldModel | None = None
    last_report = 0.0
    events = iter_fit(data, latent_dim, rng, options, body.noise_model, fitted=done_before)
    for progress in events:
        job.checkpoint()
        if progress.model is not None:
            fitted = progress.model
        now = time.perf_counter()
        if now - last_report >= PROGRESS_INTERVAL_S or progress.model is not None:
            last_report = now
            report(progress, now - started)
    if fitted is None:
        raise ValueError("the fit ended without a model")
    job.checkpoint()
    fitted, _ = calibrate(
        fitted,
        options,
        rng,
        latent_uncertainty=body.latent_uncertainty,
        tempering=body.tempering,
        object_placement=body.object_placement,
        placement_pooling=body.placement_pooling,
        shift_dimensions=shift_dimensions(data.action_dim, body.shift_along),
    )
    if pipeline is not None:
        fitted = dataclasses.replace(fitted, features=pipeline)
    return fitted, selection, time.perf_counter() - started


def _select_latent_dim(
    data: TrainingData,
    request: FitRequest,
    options: FitOptions,
    rng: np.random.Generator,
    job: Job,
    report: Callable[[FitProgress, float], None],
    started: float,
) -> LatentSelection:
    """Cross-validate ds with warm folds (:mod:`core.selection.latent_selection`: every
    candidate fitted on all the touches, each fold refitted from it). The fits use the requested
    noise model, "independent" for "auto" (it is decided by the final fit, from the chosen
    candidate's fit). On the server's Dask scheduler or the request's ``workers`` the fits and
    folds run as tasks (:mod:`app.services.fit_tasks`) and a stop cancels them; in process a
    stop ends the fit in progress at its next event."""
    body = request.body
    fold_noise: NoiseModelChoice = "independent" if body.noise_model == "auto" else body.noise_model
    n_folds = min(DEFAULT_FOLDS, int(data.touches_per_object().min()) - 2)
    n_candidates = min(DEFAULT_MAX_LATENT_DIM, data.n_objects - 1)
    # Progress in units of one fold's refit; a fit on all the touches counts as many.
    total = n_candidates * (RUNG_COST_IN_REFITS + n_folds)
    done = [0]
    on_cluster = request.scheduler is not None or body.workers is not None

    def go_on(_: FitProgress) -> bool:
        return job.stop_requested is None

    def fit_fold(
        train: TrainingData, ds: int, starts: tuple[FloatArray, ...], fold_rng: np.random.Generator
    ) -> ManifoldModel:
        job.checkpoint()
        started_from = dataclasses.replace(options, initial_latents=starts)
        try:
            return fit_manifold(train, ds, fold_rng, started_from, go_on, noise_model=fold_noise)
        except FitCancelledError:
            job.checkpoint()  # raises JobCancelled: the stop is why the fold ended
            raise

    def refit_fold(train: TrainingData, model: ManifoldModel) -> ManifoldModel:
        job.checkpoint()
        return refit_warm(train, model, options)

    def announce(units: int, phase: str, log_likelihood: float) -> None:
        done[0] += units
        progress = FitProgress(
            start=done[0],
            n_starts=total,
            iteration=0,
            log_likelihood=log_likelihood,
            best_log_likelihood=float("-inf"),
            phase=phase,
            fraction=done[0] / total,
        )
        report(progress, time.perf_counter() - started)

    def on_rung(ds: int, log_likelihood: float) -> None:
        phase = f"latent selection: ds={ds} on all the touches"
        announce(RUNG_COST_IN_REFITS, phase, log_likelihood)

    def on_fold(ds: int, fold: int, score: float) -> None:
        announce(1, f"latent selection: ds={ds}, fold {fold + 1}/{n_folds}", score)

    if not on_cluster:
        return select_latent_dim(
            data,
            fit_fold,
            rng,
            n_folds=n_folds,
            callback=on_fold,
            refit=refit_fold,
            rung_callback=on_rung,
        )
    fold_fit = FoldFit(options, fold_noise)
    with FitEngine(body.workers, request.scheduler, job.checkpoint) as engine:
        return select_latent_dim(
            data,
            fold_fit,
            rng,
            n_folds=n_folds,
            callback=on_fold,
            map=engine.fold_map,
            refit=fold_fit.refit,
            warm_map=engine.warm_map,
            rung_callback=on_rung,
        )


def _finite_or_none(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if np.isfinite(number) else None
