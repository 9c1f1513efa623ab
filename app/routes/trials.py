"""``/trials``: create, read, list; scripted next-action/observations; pause/resume/stop/abort
(one route, the action in the path)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response

from app.deps import MAX_ID, ContextDep, IdPath, Limit, Offset, SessionDep
from app.schemas import (
    NextAction,
    ObservationIn,
    ObservationResult,
    Page,
    TrialCreate,
    TrialPublic,
    TrialSummary,
)
from app.services import trial_views
from app.states import Action, RunStatus

router = APIRouter(prefix="/trials", tags=["trials"])


@router.post("", status_code=201)
def create_trial(body: TrialCreate, session: SessionDep, context: ContextDep) -> TrialPublic:
    """Start a trial: ``scripted`` (you touch), ``simulated`` or ``rig`` (the server touches)."""
    return context.trials.create(session, body)


@router.get("")
def list_trials(
    session: SessionDep,
    model_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    status: RunStatus | None = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> Page[TrialSummary]:
    """Trials, newest first, filtered by model and status."""
    return trial_views.list_page(session, model_id, status, limit, offset)


@router.get("/{trial_id}", response_model=TrialPublic)
async def get_trial(trial_id: IdPath, context: ContextDep) -> Response:
    """A trial with all its steps and its result."""
    # Served on the event loop: recorded steps are cached as JSON, so a read is one indexed
    # query plus the new steps (about a millisecond), cheaper than a hop to the thread pool.
    content = context.trial_views.read(context.database, trial_id)
    return Response(content, media_type="application/json")


@router.get("/{trial_id}/next-action")
def next_action(trial_id: IdPath, session: SessionDep, context: ContextDep) -> NextAction:
    """Scripted trials: the action the planner advises for the next touch."""
    return context.trials.next_action(session, trial_id)


@router.post("/{trial_id}/observations")
def post_observation(
    trial_id: IdPath, body: ObservationIn, session: SessionDep, context: ContextDep
) -> ObservationResult:
    """Scripted trials: the action actually performed and the observation; returns the belief."""
    return context.trials.observe(session, trial_id, body)


@router.post("/{trial_id}/{action}")
def control_trial(
    trial_id: IdPath, action: Action, session: SessionDep, context: ContextDep
) -> TrialPublic:
    """Pause, resume, stop or abort a trial (409 when its state does not allow it).

    * ``pause`` (a running trial): a server-driven trial finishes the touch in flight, records
      it, and then waits: its step count may still grow by one after this answers.
    * ``resume`` (a paused trial).
    * ``stop``: the answer of the last step recorded by then becomes the result. A
      server-driven trial starts no further touch; a touch already in flight may still be
      recorded as a step after this answers (the result stays as answered).
    * ``abort``: at once (the rig is halted); no result.
    """
    return context.trials.control(session, trial_id, action)
