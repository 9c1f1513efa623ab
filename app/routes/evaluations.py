"""``/evaluations``: policy evaluations as background jobs; progress, stop, trials, exports."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query, Response
from fastapi.responses import JSONResponse

from app.deps import MAX_ID, ContextDep, IdPath, Limit, Offset, SessionDep
from app.schemas import (
    EvaluationCreate,
    EvaluationPublic,
    EvaluationTrialPublic,
    EvaluationTrialSummary,
    Page,
)
from app.services import evaluation_views
from app.states import RunStatus

router = APIRouter(prefix="/evaluations", tags=["evaluations"])

TrialNumber = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.post("", status_code=202)
def create_evaluation(
    body: EvaluationCreate, session: SessionDep, context: ContextDep
) -> EvaluationPublic:
    """Start an evaluation (the parameters of ``activetouch evaluate``); it runs in the
    background: ``evaluation.progress`` events as trials finish, ``evaluation.status`` on
    every change of state. ``replay`` evaluates on the recorded touches of ``dataset_id``."""
    return context.evaluations.create(session, body)


@router.get("")
def list_evaluations(
    session: SessionDep,
    model_id: Annotated[int, Query(ge=1, le=MAX_ID)] | None = None,
    status: RunStatus | None = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[EvaluationPublic]:
    """Evaluations, newest first (summaries of ended jobs; ``GET /evaluations/{id}`` for the
    summary of a running one)."""
    return evaluation_views.list_page(session, model_id, status, limit, offset)


@router.get("/{evaluation_id}")
def get_evaluation(evaluation_id: IdPath, session: SessionDep) -> EvaluationPublic:
    """An evaluation: request, status, progress and the summary (so far, while it runs)."""
    return evaluation_views.get(session, evaluation_id)


@router.post("/{evaluation_id}/stop")
def stop_evaluation(
    evaluation_id: IdPath, session: SessionDep, context: ContextDep
) -> EvaluationPublic:
    """Start no further trial; the trials finished (and any in flight) are kept."""
    return context.evaluations.stop(session, evaluation_id)


@router.get("/{evaluation_id}/trials")
def list_evaluation_trials(
    evaluation_id: IdPath, session: SessionDep, limit: Limit = 100, offset: Offset = 0
) -> Page[EvaluationTrialSummary]:
    """The finished trials, in the order they finished (``number`` 1, 2, ...)."""
    return evaluation_views.trials_page(session, evaluation_id, limit, offset)


@router.get("/{evaluation_id}/trials/{number}")
def get_evaluation_trial(
    evaluation_id: IdPath, number: TrialNumber, session: SessionDep
) -> EvaluationTrialPublic:
    """One finished trial with its touches: actions, mutual information, answers and object
    probabilities after each touch."""
    return evaluation_views.trial(session, evaluation_id, number)


@router.get(
    "/{evaluation_id}/export",
    response_model=None,
    responses={
        200: {
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "text/csv": {"schema": {"type": "string"}},
            },
            "description": "The activetouch-evaluation/1 report (JSON, default) or one CSV row "
            "per trial and touch.",
        }
    },
)
def export_evaluation(
    evaluation_id: IdPath,
    session: SessionDep,
    format: Literal["json", "csv"] = "json",
) -> Response:
    """The report document (summary and every finished trial) or its touches as CSV."""
    if format == "csv":
        return Response(
            evaluation_views.export_csv(session, evaluation_id),
            media_type="text/csv",
            headers={
                "Content-Disposition": f'attachment; filename="evaluation-{evaluation_id}.csv"'
            },
        )
    return JSONResponse(
        evaluation_views.report_document(session, evaluation_id),
        headers={"Content-Disposition": f'attachment; filename="evaluation-{evaluation_id}.json"'},
    )
