"""How trials are shown: summaries, steps, the cached object names and step lists for events."""

from __future__ import annotations

import threading
from collections import OrderedDict
from functools import partial
from typing import Any

from sqlalchemy.orm import Session

from app import crud
from app.db import Database
from app.db.tables import Trial, TrialStep
from app.schemas import (
    ActionBounds,
    Belief,
    Page,
    StepPublic,
    TrialPublic,
    TrialResult,
    TrialSummary,
)


def _names(trial: Trial) -> list[str]:
    return list(trial.model.dataset.object_names)


def trial_result(trial: Trial) -> TrialResult | None:
    """The trial's answer, once it has one."""
    if trial.result_object is None:
        return None
    return TrialResult(object=trial.result_object, correct=trial.result_correct)


def step_public(step: TrialStep, names: list[str]) -> StepPublic:
    """The API view of a step."""
    return StepPublic(
        step=step.step,
        action=step.action.tolist(),
        observation=step.observation.tolist(),
        trajectory=step.trajectory,
        mutual_information=step.mutual_information,
        belief=Belief(mean=step.belief_mean.tolist(), cov=step.belief_cov.tolist()),
        probabilities=dict(zip(names, step.probabilities.tolist(), strict=True)),
        nearest_object=step.nearest_object,
        answer=step.answer,
        stop_reason=step.stop_reason,
        duration_s=step.duration_s,
        created_at=step.created_at,
    )


def _summary_fields(trial: Trial) -> dict[str, Any]:
    bounds = None
    if trial.action_lower is not None and trial.action_upper is not None:
        bounds = ActionBounds(lower=trial.action_lower.tolist(), upper=trial.action_upper.tolist())
    return {
        "id": trial.id,
        "model_id": trial.model_id,
        "mode": trial.mode,
        "policy": trial.policy,
        "status": trial.status,
        "reason": trial.reason,
        "max_steps": trial.max_steps,
        "tolerance": trial.tolerance,
        "confidence_threshold": trial.confidence_threshold,
        "prior_mean": trial.prior_mean.tolist(),
        "prior_cov": trial.prior_cov.tolist(),
        "action_bounds": bounds,
        "target": trial.target,
        "seed": trial.seed,
        "options": trial.options,
        "n_steps": trial.n_steps,
        "result": trial_result(trial),
        "created_at": trial.created_at,
        "started_at": trial.started_at,
        "finished_at": trial.finished_at,
    }


def to_summary(trial: Trial) -> TrialSummary:
    """A trial without its steps."""
    return TrialSummary(**_summary_fields(trial))


def to_public(session: Session, trial: Trial) -> TrialPublic:
    """A trial with all its steps."""
    names = _names(trial)
    steps = [step_public(s, names) for s in crud.trial_steps(session, trial.id)]
    return TrialPublic(**_summary_fields(trial), steps=steps)


class TrialViews:
    """Serialised steps of recent trials, kept in memory: a recorded step never changes, so a
    read of a running trial only converts the steps recorded since the last read.
    """

    def __init__(self, max_trials: int = 64) -> None:
        self._lock = threading.Lock()
        self._steps: OrderedDict[int, list[str]] = OrderedDict()
        self._names: dict[int, list[str]] = {}
        self._max_trials = max_trials

    def names(self, session: Session, model_id: int) -> list[str]:
        """Object names of a model (cached: they never change)."""
        with self._lock:
            cached = self._names.get(model_id)
        if cached is None:
            cached = crud.model_object_names(session, model_id)
            with self._lock:
                self._names[model_id] = cached
        return cached

    def steps(self, session: Session, trial: Trial) -> list[str]:
        """The JSON text of each of the trial's first ``trial.n_steps`` steps."""
        with self._lock:
            cached = list(self._steps.get(trial.id, ()))
        if len(cached) < trial.n_steps:
            names = self.names(session, trial.model_id)
            cached += [
                step_public(row, names).model_dump_json()
                for row in crud.trial_steps(session, trial.id, after_step=len(cached))
            ]
            with self._lock:
                if len(cached) > len(self._steps.get(trial.id, ())):
                    self._steps[trial.id] = cached
                self._steps.move_to_end(trial.id)
                while len(self._steps) > self._max_trials:
                    self._steps.popitem(last=False)
        return cached[: trial.n_steps]

    def read(self, database: Database, trial_id: int) -> bytes:
        """``GET /trials/{id}`` as JSON bytes, in a session of its own (about a millisecond)."""
        with database.session() as session:
            return self.trial_json(session, trial_id)

    def trial_json(self, session: Session, trial_id: int) -> bytes:
        """``GET /trials/{id}`` as JSON bytes."""
        trial = require(session, trial_id)
        summary = TrialSummary(**_summary_fields(trial)).model_dump_json()
        steps = ",".join(self.steps(session, trial))
        return f'{summary[:-1]},"steps":[{steps}]}}'.encode()


require = partial(crud.require, Trial)


def get(session: Session, trial_id: int) -> TrialPublic:
    """One trial with its steps."""
    return to_public(session, require(session, trial_id))


def list_page(
    session: Session, model_id: int | None, status: str | None, limit: int, offset: int
) -> Page[TrialSummary]:
    """Trials, newest first, filtered."""
    rows, count = crud.list_trials(session, model_id, status, limit, offset)
    return Page[TrialSummary](data=[to_summary(t) for t in rows], count=count)
