"""Evaluations as server jobs: many recognition trials of one model, summarised per policy.

:class:`EvaluationService` checks a request (model, world, replay dataset, policies), stores the
evaluation and runs :func:`app.evaluation.runner.run_evaluation` as a job of the job runner
(:mod:`app.services.jobs`). Each
trial is committed as an :class:`app.db.tables.EvaluationTrial` the moment the engine reports it
(``on_trial``) and announced as ``evaluation.progress`` (at most every
:data:`PROGRESS_INTERVAL_S`, and for the last trial); ``POST /evaluations/{id}/stop`` makes the
engine start no further trial (``should_stop``), the finished ones are kept. Trials run on the
server's Dask cluster when it has one (``ACTIVETOUCH_DASK_SCHEDULER``), else on the request's
``workers`` local processes, else in-process.

States follow :mod:`app.states` (``queued → running → completed | stopped | failed``); an
evaluation a previous process left running is ``failed`` with reason ``interrupted`` at start-up
(:func:`app.crud.fail_interrupted`), and so is one still running when the server shuts
down. Reads (:mod:`app.services.evaluation_views`) give the summary of the trials finished so far
while the job runs.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace

from sqlalchemy.orm import Session

from app import crud, states
from app.config import Settings
from app.db import Database
from app.db.tables import Evaluation
from app.errors import AppError, BadInputError
from app.evaluation.report import EvaluationReport
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from app.schemas import EvaluationCreate, EvaluationPublic
from app.services import datasets
from app.services.evaluation_views import build_spec, require, to_public
from app.services.events import EventBus
from app.services.jobs import INTERRUPTED, Job, JobRunner
from app.services.models import ReadyModels
from core.errors import CoreError
from core.evaluation import TrialOutcome, TrialRecord
from core.types import ManifoldModel, TrainingData

logger = logging.getLogger(__name__)

#: Seconds between two ``evaluation.progress`` events of one evaluation.
PROGRESS_INTERVAL_S = 0.2


class EvaluationService:
    """Starts, stores and stops evaluation jobs.

    Args:
        settings: The server's settings (``dask_scheduler``; ``sim_table`` or
            ``sim_table_file``: the table a rig evaluation simulates when the request names none
            or names it).
        database: Where evaluations and their trials live.
        events: Where progress is announced.
        models: Loads the fitted models evaluated.
        jobs: The job runner the evaluations run on.
    """

    def __init__(
        self,
        settings: Settings,
        database: Database,
        events: EventBus,
        models: ReadyModels,
        jobs: JobRunner,
    ) -> None:
        self._scheduler = settings.dask_scheduler or None
        self._sim_table = settings.simulated_table()
        self._database = database
        self._events = events
        self._models = models
        self._lock = threading.RLock()  # status changes and trial writes of every evaluation
        self._jobs = jobs

    # --- starting -----------------------------------------------------------------------------

    def create(self, session: Session, body: EvaluationCreate) -> EvaluationPublic:
        """Check a request, store the evaluation (``queued``) and start its job.

        Raises:
            NotFoundError: (404) no such model or dataset.
            ConflictError: (409) the model is still fitting (or failed), the dataset is still
                being collected, or the server is shutting down.
            BadInputError: (422) a replay without a dataset (or a dataset without replay); a
                replay of the model's own training data; a replay dataset whose objects or
                dimensions do not match the model; an unknown
                policy or world (the message lists the allowed values).
        """
        model = self._models.load(session, body.model_id)
        replay: TrainingData | None = None
        if body.world == "replay":
            if body.dataset_id is None:
                raise BadInputError(
                    "dataset_id: a replay evaluation needs the dataset of recorded held-out "
                    "touches to replay.",
                    field="dataset_id",
                )
            fitted_on = crud.get_model(session, body.model_id)
            if fitted_on is not None and fitted_on.dataset_id == body.dataset_id:
                raise BadInputError(
                    f"dataset_id: dataset {body.dataset_id} is the one model {body.model_id} "
                    "was fitted to; a replay evaluates on held-out touches, never used for "
                    "fitting.",
                    field="dataset_id",
                )
            replay = datasets.load_training_data(session, body.dataset_id)
            if model.features is not None and datasets.has_raw_touches(session, body.dataset_id):
                # Recorded raw touches are seen as the model sees a touch: through its pipeline.
                replay = datasets.featurised_data(session, body.dataset_id, model.features)
        elif body.dataset_id is not None:
            raise BadInputError(
                f"dataset_id: only a replay evaluation takes a dataset (world is {body.world!r}).",
                field="dataset_id",
            )
        if body.world == "rig" and body.table is None:
            # The rig world simulates this server's table unless another is named.
            body = body.model_copy(update={"table": self._sim_table.name})
        spec = build_spec(body)
        if spec.table == self._sim_table.name:  # the server's table, read from its file too
            spec = replace(spec, table=self._sim_table)
        spec.check(model, replay)
        targets = spec.target_names(model)
        total = len(spec.policies) * len(targets) * spec.trials_per_target
        workers = None if self._scheduler else body.workers
        self._jobs.check_open()
        row = crud.create_evaluation(
            session,
            model_id=body.model_id,
            dataset_id=body.dataset_id,
            spec=body.model_dump(mode="json"),
            status="queued",
            done=0,
            total=total,
            steps=spec.steps_used(model, replay),
            workers=workers,
        )
        evaluation_id = row.id
        self._jobs.commit_and_start(
            session,
            "evaluation",
            evaluation_id,
            lambda job: self._run(job, evaluation_id, model, spec, replay, workers),
            announce=lambda: self._announce(row),
            fail=lambda reason: self._finish(evaluation_id, "failed", reason, None),
        )
        return to_public(row)

    # --- the job ------------------------------------------------------------------------------

    def _run(
        self,
        job: Job,
        evaluation_id: int,
        model: ManifoldModel,
        spec: EvaluationSpec,
        replay: TrainingData | None,
        workers: int | None,
    ) -> None:
        """The job: run the trials (stored as they end), then store the report's summary."""
        try:
            if not self._set_running(evaluation_id):
                return
            progress = _Progress(self, evaluation_id)
            report = run_evaluation(
                model,
                spec,
                replay=replay,
                workers=workers,
                scheduler=self._scheduler,
                on_trial=progress.store,
                should_stop=lambda: job.stop_requested is not None,
            )
            progress.flush()
            if job.stop_requested == "shutdown":
                self._finish(evaluation_id, "failed", INTERRUPTED, report)
            else:
                status = "stopped" if report.stopped else "completed"
                self._finish(evaluation_id, status, None, report)
        except (AppError, CoreError, ValueError, OSError) as exc:
            logger.warning("evaluation %d failed: %s", evaluation_id, exc)
            self._finish(evaluation_id, "failed", f"{type(exc).__name__}: {exc}", None)
        except Exception as exc:  # a bug must still leave the evaluation failed, not running
            logger.exception("evaluation %d crashed", evaluation_id)
            self._finish(
                evaluation_id, "failed", f"internal error: {type(exc).__name__}: {exc}", None
            )

    def _set_running(self, evaluation_id: int) -> bool:
        """``queued → running``; false when it was stopped before it started."""
        with self._lock, self._database.session() as session:
            row = require(session, evaluation_id)
            if row.status != "queued":
                return False
            crud.set_evaluation_status(session, row, "running")
            session.commit()
        self._announce(row)
        return True

    def store_trial(self, evaluation_id: int, record: TrialOutcome) -> tuple[Evaluation, int]:
        """Commit one finished trial (refused ones too); return the row and the trial's number."""
        with self._lock, self._database.session() as session:
            row = require(session, evaluation_id)
            trial = crud.add_evaluation_trial(session, row, record.to_dict())
            session.commit()
            return row, trial.number

    def publish_progress(self, row: Evaluation, number: int, record: TrialOutcome | None) -> None:
        """Announce an evaluation's progress (``evaluation.progress``) after trial ``number``."""
        data: dict[str, object] = {
            "evaluation_id": row.id,
            "status": row.status,
            "done": row.done,
            "total": row.total,
            "number": number,
        }
        if record is not None:
            data.update(
                policy=record.policy,
                target=record.target,
                trial=record.trial,
                correct=record.correct,
                touches=record.touches,
                refused=not isinstance(record, TrialRecord),
            )
        self._events.publish("evaluation.progress", data)

    def _finish(
        self,
        evaluation_id: int,
        status: str,
        reason: str | None,
        report: EvaluationReport | None,
    ) -> None:
        """Store the report's summary and end the evaluation (a stop may have ended it already)."""
        with self._lock, self._database.session() as session:
            row = require(session, evaluation_id)
            if report is not None:
                document = report.to_dict(include_trials=False)
                document.pop("trials", None)
                document.pop("refused", None)  # the refused trials are trial rows too
                row.summary = document
                row.seconds = report.seconds
                row.workers = report.workers
                row.steps = report.steps
                if status == "completed":
                    row.total = row.done
            if row.status in states.ACTIVE:
                crud.set_evaluation_status(session, row, status, reason)
            session.commit()
        self._announce(row)

    def _announce(self, row: Evaluation) -> None:
        self._events.publish(
            "evaluation.status",
            {
                "evaluation_id": row.id,
                "status": row.status,
                "reason": row.reason,
                "done": row.done,
                "total": row.total,
                "model_id": row.model_id,
            },
        )

    # --- control ------------------------------------------------------------------------------

    def stop(self, session: Session, evaluation_id: int) -> EvaluationPublic:
        """Start no further trial; the finished ones are kept (409 once it has ended)."""
        with self._lock:
            row = require(session, evaluation_id)
            target = states.check_action(f"evaluation {evaluation_id}", row.status, "stop")
            crud.set_evaluation_status(session, row, target, reason="stop requested")
            session.commit()
            job = self._jobs.handle("evaluation", evaluation_id)
            if job is not None:
                job.request_stop("stopped")
        self._announce(row)
        return to_public(row)


class _Progress:
    """The ``on_trial`` of one job: commit each trial, announce progress now and then."""

    def __init__(self, service: EvaluationService, evaluation_id: int) -> None:
        self._service = service
        self._evaluation_id = evaluation_id
        self._last_event = 0.0
        self._pending: tuple[Evaluation, int, TrialOutcome] | None = None

    def store(self, record: TrialOutcome) -> None:
        row, number = self._service.store_trial(self._evaluation_id, record)
        now = time.monotonic()
        if now - self._last_event >= PROGRESS_INTERVAL_S:
            self._last_event = now
            self._pending = None
            self._service.publish_progress(row, number, record)
        else:
            self._pending = (row, number, record)

    def flush(self) -> None:
        """Announce the last trial if its event was held back."""
        if self._pending is not None:
            row, number, record = self._pending
            self._pending = None
            self._service.publish_progress(row, number, record)
