"""Every database query of the app, in one place.

Functions take a :class:`~sqlalchemy.orm.Session` and either read or add/modify rows; the caller
owns the transaction (``commit``), except where a function says it commits.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import datetime
from typing import Any, TypeVar

from sqlalchemy import Select, delete, func, select, update
from sqlalchemy.orm import Session

from app.db.tables import (
    Dataset,
    Evaluation,
    EvaluationTrial,
    EventRecord,
    FloatArray,
    ModelRecord,
    ObjectRecord,
    RequestAudit,
    Run,
    Sample,
    Trial,
    TrialStep,
    utc_now,
)
from app.errors import NotFoundError
from app.states import ACTIVE, MODEL_ACTIVE

RowT = TypeVar("RowT", Dataset, ModelRecord, Trial, Run, Evaluation)
_RowT = TypeVar("_RowT")

#: What a 404 calls a row of each table it answers for (a run is called by its kind).
_NOUNS: dict[type[Any], str] = {
    Dataset: "dataset",
    ModelRecord: "model",
    Trial: "trial",
    Evaluation: "evaluation",
}


def require(table: type[RowT], session: Session, row_id: int, kind: str | None = None) -> RowT:
    """The row of ``table`` with this id (a run: of this ``kind``), or a 404 naming it.

    The services bind ``table`` (``require = partial(crud.require, Dataset)``), so every
    missing id is answered alike: ``{"detail": "Dataset 7 does not exist.", "dataset_id": 7}``.

    Raises:
        NotFoundError: No such row (or a run of another kind).
    """
    row = session.get(table, row_id)
    if row is None or (kind is not None and getattr(row, "kind", None) != kind):
        noun = kind or _NOUNS[table]
        raise NotFoundError(
            f"{noun.capitalize()} {row_id} does not exist.", **{f"{noun}_id": row_id}
        )
    return row


def _added(session: Session, row: _RowT) -> _RowT:
    """Add ``row`` and flush it, so it has an id."""
    session.add(row)
    session.flush()
    return row


def _page(
    session: Session, query: Select[_RowT], order: Any, limit: int, offset: int
) -> tuple[list[_RowT], int]:
    """Rows ``offset+1 .. offset+limit`` of ``query`` in ``order``, and how many it has in all."""
    rows = session.scalars(query.order_by(order).limit(limit).offset(offset)).all()
    count = session.scalar(select(func.count()).select_from(query.subquery())) or 0
    return list(rows), count


def _where_given(query: Select[_RowT], *filters: tuple[Any, object | None]) -> Select[_RowT]:
    """``query`` keeping the rows whose ``column == value``, for every ``(column, value)`` whose
    value is given (not ``None``)."""
    for column, value in filters:
        if value is not None:
            query = query.where(column == value)
    return query


def _set_status(row: Trial | Run | Evaluation, status: str, reason: str | None) -> datetime:
    """Change a trial's, run's or evaluation's status (timestamps follow); returns the time."""
    row.status = status
    if reason is not None:
        row.reason = reason
    now = utc_now()
    if status == "running" and row.started_at is None:
        row.started_at = now
    if status not in ACTIVE:
        row.finished_at = now
    return now


# --- objects ----------------------------------------------------------------------------------


def get_or_create_objects(session: Session, names: Iterable[str]) -> dict[str, ObjectRecord]:
    """The object rows of ``names``, creating the missing ones."""
    wanted = list(dict.fromkeys(names))
    found = {
        row.name: row
        for row in session.scalars(select(ObjectRecord).where(ObjectRecord.name.in_(wanted)))
    }
    for name in wanted:
        if name not in found:
            row = ObjectRecord(name=name, notes="", properties={})
            session.add(row)
            found[name] = row
    session.flush()
    return found


def set_object_slot(session: Session, name: str, slot: int) -> ObjectRecord:
    """Record the turntable slot of an object (created if new)."""
    row = get_or_create_objects(session, [name])[name]
    row.slot = slot
    return row


def get_object_by_name(session: Session, name: str) -> ObjectRecord | None:
    """The object called ``name``, if any."""
    return session.scalars(select(ObjectRecord).where(ObjectRecord.name == name)).first()


# --- datasets ---------------------------------------------------------------------------------


def create_dataset(
    session: Session,
    *,
    name: str,
    source: str,
    status: str,
    object_names: Sequence[str],
    action_dim: int,
    observation_dim: int,
    touch_duration_s: float | None = None,
) -> Dataset:
    """Add an empty dataset row (flushed, so it has an id)."""
    return _added(
        session,
        Dataset(
            name=name,
            source=source,
            status=status,
            object_names=list(object_names),
            action_dim=action_dim,
            observation_dim=observation_dim,
            n_samples=0,
            touch_duration_s=touch_duration_s,
        ),
    )


def add_samples(
    session: Session,
    dataset: Dataset,
    samples: Iterable[
        tuple[str, FloatArray, FloatArray, dict[str, Any] | None, int | None, float | None]
    ],
) -> int:
    """Append ``(object name, action, observation, raw, placement, time_s)`` samples; return how
    many were added."""
    rows = list(samples)
    objects = get_or_create_objects(session, (name for name, *_ in rows))
    start = dataset.n_samples
    for offset, (name, action, observation, raw, placement, time_s) in enumerate(rows):
        session.add(
            Sample(
                dataset_id=dataset.id,
                position=start + offset,
                object_id=objects[name].id,
                action=action,
                observation=observation,
                raw=raw,
                placement=placement,
                time_s=time_s,
            )
        )
    dataset.n_samples = start + len(rows)
    names = list(dataset.object_names)
    new_names = [name for name in dict.fromkeys(n for n, *_ in rows) if name not in names]
    if new_names:
        dataset.object_names = names + new_names
    return len(rows)


def get_dataset(session: Session, dataset_id: int) -> Dataset | None:
    """The dataset with this id, if any."""
    return session.get(Dataset, dataset_id)


def list_datasets(session: Session, limit: int, offset: int) -> tuple[list[Dataset], int]:
    """Datasets, newest first, and the total count."""
    return _page(session, select(Dataset), Dataset.id.desc(), limit, offset)


def dataset_samples(
    session: Session, dataset_id: int
) -> list[tuple[str, FloatArray, FloatArray, int | None, float | None]]:
    """``(object name, action, observation, placement, time_s)`` of every sample, in upload
    order."""
    rows = session.execute(
        select(
            ObjectRecord.name, Sample.action, Sample.observation, Sample.placement, Sample.time_s
        )
        .join(ObjectRecord, Sample.object_id == ObjectRecord.id)
        .where(Sample.dataset_id == dataset_id)
        .order_by(Sample.position)
    ).all()
    return [
        (str(name), action, y, placement, time_s) for name, action, y, placement, time_s in rows
    ]


def dataset_raw_samples(
    session: Session, dataset_id: int
) -> list[tuple[str, FloatArray, dict[str, Any] | None, int | None, float | None]]:
    """``(object name, action, raw, placement, time_s)`` of every sample, in upload order."""
    rows = session.execute(
        select(ObjectRecord.name, Sample.action, Sample.raw, Sample.placement, Sample.time_s)
        .join(ObjectRecord, Sample.object_id == ObjectRecord.id)
        .where(Sample.dataset_id == dataset_id)
        .order_by(Sample.position)
    ).all()
    return [
        (str(name), action, raw, placement, time_s) for name, action, raw, placement, time_s in rows
    ]


# --- models -----------------------------------------------------------------------------------


def create_model(session: Session, **fields: Any) -> ModelRecord:
    """Add a model row (flushed, so it has an id)."""
    return _added(session, ModelRecord(**fields))


def get_model(session: Session, model_id: int) -> ModelRecord | None:
    """The model with this id, if any."""
    return session.get(ModelRecord, model_id)


def list_models(
    session: Session, status: str | None, limit: int, offset: int
) -> tuple[list[ModelRecord], int]:
    """Models, newest first (optionally of one status), and the count."""
    query = _where_given(select(ModelRecord), (ModelRecord.status, status))
    return _page(session, query, ModelRecord.id.desc(), limit, offset)


# --- trials -----------------------------------------------------------------------------------


def create_trial(session: Session, **fields: Any) -> Trial:
    """Add a trial row (flushed, so it has an id)."""
    return _added(session, Trial(**fields))


def get_trial(session: Session, trial_id: int) -> Trial | None:
    """The trial with this id, if any."""
    return session.get(Trial, trial_id)


def list_trials(
    session: Session, model_id: int | None, status: str | None, limit: int, offset: int
) -> tuple[list[Trial], int]:
    """Trials, newest first, filtered by model and status, and the count."""
    query = _where_given(select(Trial), (Trial.model_id, model_id), (Trial.status, status))
    return _page(session, query, Trial.id.desc(), limit, offset)


def trial_steps(session: Session, trial_id: int, after_step: int = 0) -> list[TrialStep]:
    """The steps of a trial numbered above ``after_step`` (all by default), in order."""
    return list(
        session.scalars(
            select(TrialStep)
            .where(TrialStep.trial_id == trial_id, TrialStep.step > after_step)
            .order_by(TrialStep.step)
        ).all()
    )


def model_object_names(session: Session, model_id: int) -> list[str]:
    """Object names of a model (its dataset's order)."""
    names = session.scalar(
        select(Dataset.object_names)
        .join(ModelRecord, ModelRecord.dataset_id == Dataset.id)
        .where(ModelRecord.id == model_id)
    )
    return list(names or [])


def add_trial_step(session: Session, trial: Trial, **fields: Any) -> TrialStep:
    """Add step ``trial.n_steps + 1`` and bump the trial's step count."""
    step = TrialStep(trial_id=trial.id, step=trial.n_steps + 1, **fields)
    session.add(step)
    trial.n_steps = step.step
    return step


def set_trial_status(
    session: Session, trial: Trial, status: str, reason: str | None = None
) -> None:
    """Change a trial's status (timestamps follow); the caller checked the transition."""
    _set_status(trial, status, reason)


# --- runs -------------------------------------------------------------------------------------


def create_run(session: Session, **fields: Any) -> Run:
    """Add a run row (flushed, so it has an id)."""
    return _added(session, Run(**fields))


def list_runs(
    session: Session, kind: str, status: str | None, limit: int, offset: int
) -> tuple[list[Run], int]:
    """Runs of a kind, newest first, and the count."""
    query = _where_given(select(Run), (Run.kind, kind), (Run.status, status))
    return _page(session, query, Run.id.desc(), limit, offset)


def set_run_status(session: Session, run: Run, status: str, reason: str | None = None) -> None:
    """Change a run's status (timestamps follow); the caller checked the transition."""
    _set_status(run, status, reason)


# --- recovery after a restart -----------------------------------------------------------------


def fail_interrupted(session: Session, reason: str) -> dict[str, list[int]]:
    """Mark every job a previous process left unfinished as ``failed`` with ``reason``: trials,
    runs and evaluations queued, running or paused, models queued or fitting, and datasets still
    collecting.

    Steps, samples and finished evaluation trials already recorded are kept. Commits.

    Returns:
        The ids that were changed, per kind (``trials``, ``runs``, ``evaluations``, ``models``,
        ``datasets``).
    """
    now = utc_now()
    changed: dict[str, list[int]] = {}
    for kind, table, active in (
        ("trials", Trial, ACTIVE),
        ("runs", Run, ACTIVE),
        ("evaluations", Evaluation, ACTIVE),
        ("models", ModelRecord, MODEL_ACTIVE),
    ):
        ids = list(session.scalars(select(table.id).where(table.status.in_(active))).all())
        if ids:
            session.execute(
                update(table)
                .where(table.id.in_(ids))
                .values(status="failed", reason=reason, finished_at=now)
            )
        changed[kind] = ids
    collecting = list(
        session.scalars(select(Dataset.id).where(Dataset.status == "collecting")).all()
    )
    if collecting:
        session.execute(update(Dataset).where(Dataset.id.in_(collecting)).values(status="failed"))
    changed["datasets"] = collecting
    session.commit()
    return changed


# --- events -----------------------------------------------------------------------------------


def add_event(session: Session, type_: str, data: dict[str, Any], created_at: datetime) -> int:
    """Store an event; return its sequence id. Commits."""
    record = EventRecord(type=type_, data=data, created_at=created_at)
    session.add(record)
    session.commit()
    return record.id


def events_after(session: Session, after_id: int, limit: int) -> list[EventRecord]:
    """Events with id > ``after_id``, oldest first."""
    return list(
        session.scalars(
            select(EventRecord)
            .where(EventRecord.id > after_id)
            .order_by(EventRecord.id)
            .limit(limit)
        ).all()
    )


def last_event_id(session: Session) -> int:
    """The id of the newest stored event (0 when there is none)."""
    return session.scalar(select(func.max(EventRecord.id))) or 0


def prune_events(session: Session, keep: int) -> None:
    """Delete all but the newest ``keep`` events. Commits."""
    newest = last_event_id(session)
    session.execute(delete(EventRecord).where(EventRecord.id <= newest - keep))
    session.commit()


def ping(session: Session) -> None:
    """A trivial query: raises if the database cannot be read."""
    session.execute(select(1))


def list_objects(session: Session, limit: int, offset: int) -> tuple[list[ObjectRecord], int]:
    """Registered objects by name, and the count."""
    return _page(session, select(ObjectRecord), ObjectRecord.name, limit, offset)


# --- evaluations ------------------------------------------------------------------------------


def create_evaluation(session: Session, **fields: Any) -> Evaluation:
    """Add an evaluation row (flushed, so it has an id)."""
    return _added(session, Evaluation(**fields))


def get_evaluation(session: Session, evaluation_id: int) -> Evaluation | None:
    """The evaluation with this id, if any."""
    return session.get(Evaluation, evaluation_id)


def list_evaluations(
    session: Session, model_id: int | None, status: str | None, limit: int, offset: int
) -> tuple[list[Evaluation], int]:
    """Evaluations, newest first, filtered by model and status, and the count."""
    query = _where_given(
        select(Evaluation), (Evaluation.model_id, model_id), (Evaluation.status, status)
    )
    return _page(session, query, Evaluation.id.desc(), limit, offset)


def set_evaluation_status(
    session: Session, evaluation: Evaluation, status: str, reason: str | None = None
) -> None:
    """Change an evaluation's status (timestamps follow); the caller checked the transition."""
    evaluation.updated_at = _set_status(evaluation, status, reason)


def add_evaluation_trial(
    session: Session, evaluation: Evaluation, record: dict[str, Any]
) -> EvaluationTrial:
    """Add a finished trial (a ``TrialRecord.to_dict()``, or a ``RefusedTrial.to_dict()``, which
    has ``refused``) as number ``done + 1``; bump ``done``.

    Raises:
        KeyError: ``record`` lacks ``policy``, ``target``, ``trial``, ``correct`` or ``touches``.
    """
    row = EvaluationTrial(
        evaluation_id=evaluation.id,
        number=evaluation.done + 1,
        policy=str(record["policy"]),
        target=str(record["target"]),
        trial=int(record["trial"]),
        correct=bool(record["correct"]),
        touches=int(record["touches"]),
        refused=bool(record.get("refused")),
        record=record,
    )
    session.add(row)
    evaluation.done = row.number
    evaluation.updated_at = utc_now()
    return row


def evaluation_trials(session: Session, evaluation_id: int) -> list[EvaluationTrial]:
    """The finished trials of an evaluation, in the order they finished."""
    return list(
        session.scalars(
            select(EvaluationTrial)
            .where(EvaluationTrial.evaluation_id == evaluation_id)
            .order_by(EvaluationTrial.number)
        ).all()
    )


def evaluation_trial_page(
    session: Session, evaluation_id: int, limit: int, offset: int
) -> tuple[list[EvaluationTrial], int]:
    """Finished trials ``offset+1 .. offset+limit`` (in finishing order), and the count."""
    query = select(EvaluationTrial).where(EvaluationTrial.evaluation_id == evaluation_id)
    return _page(session, query, EvaluationTrial.number, limit, offset)


def get_evaluation_trial(
    session: Session, evaluation_id: int, number: int
) -> EvaluationTrial | None:
    """Finished trial ``number`` (1-based, in finishing order) of an evaluation, if any."""
    return session.scalars(
        select(EvaluationTrial).where(
            EvaluationTrial.evaluation_id == evaluation_id, EvaluationTrial.number == number
        )
    ).first()


def add_request_audits(session: Session, rows: Iterable[dict[str, Any]]) -> int:
    """Insert request-audit rows (``RequestAudit`` columns as keys). Commits; returns how many."""
    records = [RequestAudit(**row) for row in rows]
    session.add_all(records)
    session.commit()
    return len(records)


def prune_request_audits(session: Session, keep: int) -> int:
    """Delete all but the newest ``keep`` request-audit rows. Commits; returns how many went."""
    newest = session.scalar(select(func.max(RequestAudit.id))) or 0
    result = session.execute(delete(RequestAudit).where(RequestAudit.id <= newest - keep))
    session.commit()
    return int(getattr(result, "rowcount", 0) or 0)


def list_request_audits(
    session: Session,
    limit: int,
    offset: int,
    method: str | None = None,
    path_prefix: str | None = None,
) -> tuple[list[RequestAudit], int]:
    """Recorded mutating requests, newest first, and the count (filtered by method and path)."""
    query = _where_given(select(RequestAudit), (RequestAudit.method, method))
    if path_prefix is not None:
        query = query.where(RequestAudit.path.startswith(path_prefix, autoescape=True))
    return _page(session, query, RequestAudit.id.desc(), limit, offset)
