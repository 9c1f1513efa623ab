"""How evaluations are shown: the API views, the summary so far, the report and CSV exports.

The summary of a finished job is the one its report gave (stored). While a job runs, or after it
failed without a report, the summary is that of the trials finished so far (the engine's
:class:`~app.evaluation.report.EvaluationReport` rebuilt from the stored trials), marked
``"partial": true``. Exports rebuild the report the same way, so a completed evaluation exports
exactly the engine's document and CSV. A stored summary of an older format (``/1``, before each
policy's calibration was reported) is summarised again from the stored trials when one
evaluation is read (the list shows the stored one, with no calibration).
"""

from __future__ import annotations

import csv
import io
from functools import partial
from typing import Any

from sqlalchemy.orm import Session

from app import crud
from app.db.tables import Evaluation, EvaluationTrial, utc_now
from app.errors import BadInputError, NotFoundError
from app.evaluation.report import FORMAT, EvaluationReport
from app.evaluation.spec import EvaluationSpec
from app.schemas import (
    EvaluationCreate,
    EvaluationPublic,
    EvaluationTrialPublic,
    EvaluationTrialSummary,
    Page,
    TrialRefusal,
    from_row,
)
from core.errors import CoreError
from core.evaluation import RefusedTrial, TrialRecord, outcome_from_dict


def build_spec(body: EvaluationCreate) -> EvaluationSpec:
    """The engine's spec of a request.

    Raises:
        BadInputError: The engine refuses a value (the message names it).
    """
    try:
        return EvaluationSpec(
            world=body.world,
            policies=tuple(body.policies),
            trials_per_target=body.trials_per_target,
            steps=body.steps,
            confidence=body.confidence,
            seed=body.seed,
            targets=tuple(body.targets) if body.targets is not None else None,
            table=body.table,
            placement=body.placement,
            trial_likelihood=body.trial_likelihood,
            plan_under=body.plan_under,
            stop_at_confidence=body.stop_at_confidence,
        )
    except (CoreError, ValueError, TypeError) as exc:
        raise BadInputError(f"evaluation: {exc}", field="body") from exc


require = partial(crud.require, Evaluation)


def to_public(row: Evaluation, summary: dict[str, Any] | None = None) -> EvaluationPublic:
    """The API view of an evaluation (``summary``: the stored one unless given)."""
    return from_row(EvaluationPublic, row, summary=summary if summary is not None else row.summary)


def _records(
    rows: list[EvaluationTrial],
) -> tuple[tuple[TrialRecord, ...], tuple[RefusedTrial, ...]]:
    """The stored trials as engine records: (completed, refused)."""
    outcomes = [outcome_from_dict(r.record) for r in rows]
    return (
        tuple(o for o in outcomes if isinstance(o, TrialRecord)),
        tuple(o for o in outcomes if isinstance(o, RefusedTrial)),
    )


def stored_report(session: Session, row: Evaluation) -> EvaluationReport:
    """The evaluation's report rebuilt from what is stored: its spec, every finished trial, T,
    time (so far, while it runs) and workers; ``stopped`` once it ended without completing. For
    a completed job it is the engine's report (the same document and CSV)."""
    body = EvaluationCreate.model_validate(row.spec)
    seconds = row.seconds
    if seconds is None:  # not ended with a report: the time it has run (or ran) so far
        started = row.started_at or row.created_at
        seconds = max(0.0, ((row.finished_at or utc_now()) - started).total_seconds())
    records, refused = _records(crud.evaluation_trials(session, row.id))
    return EvaluationReport(
        spec=build_spec(body),
        records=records,
        refused=refused,
        seconds=seconds,
        workers=row.workers if row.workers is not None else 1,
        stopped=row.status in ("stopped", "aborted", "failed"),
        object_names=tuple(crud.model_object_names(session, row.model_id)),
        steps=row.steps,
    )


def stored_summary(session: Session, row: Evaluation) -> dict[str, Any]:
    """The summary document (without trials) of the stored trials, in today's format."""
    document = stored_report(session, row).to_dict(include_trials=False)
    document.pop("trials", None)
    document.pop("refused", None)  # the refused trials are trial rows too
    return document


def partial_summary(session: Session, row: Evaluation) -> dict[str, Any] | None:
    """The summary document (without trials) of the trials finished so far; ``None`` if none."""
    if row.done == 0:
        return None
    return {**stored_summary(session, row), "partial": True}


def get(session: Session, evaluation_id: int) -> EvaluationPublic:
    """One evaluation, with the summary of its trials so far while it has no final one, and a
    final one of an older format summarised again from its trials."""
    row = require(session, evaluation_id)
    if row.summary is None:
        return to_public(row, partial_summary(session, row))
    if row.summary.get("format") != FORMAT:
        return to_public(row, stored_summary(session, row))
    return to_public(row)


def list_page(
    session: Session, model_id: int | None, status: str | None, limit: int, offset: int
) -> Page[EvaluationPublic]:
    """Evaluations, newest first (the stored summaries only: null until a job has ended)."""
    rows, count = crud.list_evaluations(session, model_id, status, limit, offset)
    return Page[EvaluationPublic](data=[to_public(r) for r in rows], count=count)


def _trial_summary(row: EvaluationTrial) -> EvaluationTrialSummary:
    answers = row.record.get("answers") or []
    refusal = row.record.get("refused") if row.refused else None
    return EvaluationTrialSummary(
        number=row.number,
        policy=row.policy,
        target=row.target,
        trial=row.trial,
        correct=row.correct,
        touches=row.touches,
        answer=str(answers[-1]) if answers and not row.refused else None,
        stop_reason=row.record.get("stop_reason"),
        refused=row.refused,
        refusal=TrialRefusal.model_validate(refusal) if refusal else None,
    )


def trials_page(
    session: Session, evaluation_id: int, limit: int, offset: int
) -> Page[EvaluationTrialSummary]:
    """The finished trials of an evaluation, in the order they finished."""
    require(session, evaluation_id)
    rows, count = crud.evaluation_trial_page(session, evaluation_id, limit, offset)
    return Page[EvaluationTrialSummary](data=[_trial_summary(r) for r in rows], count=count)


def trial(session: Session, evaluation_id: int, number: int) -> EvaluationTrialPublic:
    """Finished trial ``number`` (1-based, in finishing order), with its touches."""
    evaluation = require(session, evaluation_id)
    row = crud.get_evaluation_trial(session, evaluation_id, number)
    if row is None:
        raise NotFoundError(
            f"Evaluation {evaluation_id} has no finished trial {number} "
            f"({evaluation.done} finished so far).",
            evaluation_id=evaluation_id,
            number=number,
        )
    return EvaluationTrialPublic(
        **_trial_summary(row).model_dump(),
        evaluation_id=evaluation_id,
        model_id=evaluation.model_id,
        objects=crud.model_object_names(session, evaluation.model_id),
        record=row.record,
    )


def report_document(session: Session, evaluation_id: int) -> dict[str, Any]:
    """The ``activetouch-evaluation/2`` document: the summary and every finished trial.

    For a job that has not completed, the summary is that of the trials finished so far.
    """
    return stored_report(session, require(session, evaluation_id)).to_dict()


def export_csv(session: Session, evaluation_id: int) -> str:
    """Every touch of every finished trial, one CSV row each (the engine's columns)."""
    report = stored_report(session, require(session, evaluation_id))
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(report.csv_rows())
    return out.getvalue()
