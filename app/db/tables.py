"""SQLAlchemy 2 tables: objects, datasets and samples, models, trials and steps, runs, events.

Arrays are stored as JSON lists of floats written with ``repr`` (Python's ``json`` does that), which
round-trips float64 exactly; :class:`FloatArrayType` turns them back into ``float64`` arrays.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Any

import numpy as np
import numpy.typing as npt
from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Dialect,
    Float,
    ForeignKey,
    Integer,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
    false,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

FloatArray = npt.NDArray[np.float64]


def utc_now() -> datetime:
    """The current time, timezone-aware UTC."""
    return datetime.now(UTC)


class FloatArrayType(TypeDecorator[FloatArray]):
    """A float64 array of any shape, stored as JSON nested lists (exact round trip)."""

    impl = Text
    cache_ok = True

    def process_bind_param(self, value: Any, dialect: Dialect) -> str | None:
        if value is None:
            return None
        array = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(array)):
            raise ValueError("FloatArrayType: refusing to store a non-finite value.")
        return json.dumps(array.tolist(), allow_nan=False)

    def process_result_value(self, value: str | None, dialect: Dialect) -> FloatArray | None:
        if value is None:
            return None
        return np.asarray(json.loads(value), dtype=np.float64)


class UTCDateTime(TypeDecorator[datetime]):
    """A timezone-aware UTC datetime (SQLite stores it naive; UTC is put back on reading)."""

    impl = DateTime
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("UTCDateTime: refusing a naive datetime.")
        return value.astimezone(UTC).replace(tzinfo=None)

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        return None if value is None else value.replace(tzinfo=UTC)


class Base(DeclarativeBase):
    """Declarative base of every table."""


class ObjectRecord(Base):
    """A physical object (or a named object of a dataset)."""

    __tablename__ = "objects"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    slot: Mapped[int | None] = mapped_column(Integer, default=None)
    notes: Mapped[str] = mapped_column(Text, default="")
    properties: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)


class Dataset(Base):
    """Tactile samples of known objects, uploaded or collected on the rig.

    ``object_names`` keeps the order of first appearance: it is the latent order of models.
    """

    __tablename__ = "datasets"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    source: Mapped[str] = mapped_column(String(20))  # upload | collection | import
    status: Mapped[str] = mapped_column(String(20), default="ready")  # collecting|ready|failed
    object_names: Mapped[list[str]] = mapped_column(JSON, default=list)
    action_dim: Mapped[int] = mapped_column(Integer)
    observation_dim: Mapped[int] = mapped_column(Integer)
    n_samples: Mapped[int] = mapped_column(Integer, default=0)
    # How long every touch lasted as planned (s): an action means a trajectory of that duration.
    touch_duration_s: Mapped[float | None] = mapped_column(Float, default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)

    samples: Mapped[list[Sample]] = relationship(
        back_populates="dataset", cascade="all, delete-orphan", order_by="Sample.position"
    )


class Sample(Base):
    """One touch: object, action x (dx,), features y (dy,), optional raw time series.

    ``placement``: which placement of its object the touch met (0, 1, …; touches of one object
    with one number shared it), ``None`` when it was not recorded (an upload without placements,
    a row from before revision 0006). ``time_s``: when the touch was made, in seconds since its
    collection's first touch (finite), ``None`` when it was not recorded (an upload without
    times, a row from before revision 0007).
    """

    __tablename__ = "samples"
    __table_args__ = (UniqueConstraint("dataset_id", "position"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    dataset_id: Mapped[int] = mapped_column(ForeignKey("datasets.id", ondelete="CASCADE"))
    position: Mapped[int] = mapped_column(Integer)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id"))
    action: Mapped[FloatArray] = mapped_column(FloatArrayType)
    observation: Mapped[FloatArray] = mapped_column(FloatArrayType)
    raw: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    placement: Mapped[int | None] = mapped_column(Integer, default=None)
    time_s: Mapped[float | None] = mapped_column(Float, default=None)

    dataset: Mapped[Dataset] = relationship(back_populates="samples")
    object: Mapped[ObjectRecord] = relationship()


class ModelRecord(Base):
    """A fitted (or fitting) object manifold.

    The GP posterior is not stored: it is recomputed from the dataset, latents and
    hyperparameters (deterministic), so the stored arrays are the whole model. ``posterior``
    records how it was conditioned (the model document's ``posterior`` field: structure and, for
    a sparse model, its inducing touches); ``None`` on rows from before revision 0002, which are
    rebuilt with :func:`core.gp.posterior.condition`'s default structure.
    """

    __tablename__ = "models"

    id: Mapped[int] = mapped_column(primary_key=True)
    dataset_id: Mapped[int] = mapped_column(ForeignKey("datasets.id"))
    status: Mapped[str] = mapped_column(String(20), default="fitting")  # app.states.ModelStatus
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    latent_dim: Mapped[int] = mapped_column(Integer)
    optimizer: Mapped[str] = mapped_column(String(20), default="lbfgs")
    restarts: Mapped[int] = mapped_column(Integer, default=0)
    seed: Mapped[int | None] = mapped_column(Integer, default=None)
    latents: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    signal_variance: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    noise_variance: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    latent_lengthscales: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    action_lengthscales: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    log_likelihood: Mapped[float | None] = mapped_column(Float, default=None)
    fit_seconds: Mapped[float | None] = mapped_column(Float, default=None)
    diagnostics: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    progress: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)
    posterior: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)

    dataset: Mapped[Dataset] = relationship()


class Trial(Base):
    """One recognition run and its settings; its steps are :class:`TrialStep` rows."""

    __tablename__ = "trials"

    id: Mapped[int] = mapped_column(primary_key=True)
    model_id: Mapped[int] = mapped_column(ForeignKey("models.id"), index=True)
    mode: Mapped[str] = mapped_column(String(20))  # scripted | simulated | rig
    policy: Mapped[str] = mapped_column(String(20))  # active | passive | fixed
    status: Mapped[str] = mapped_column(String(20), default="queued", index=True)
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    max_steps: Mapped[int] = mapped_column(Integer)
    tolerance: Mapped[float] = mapped_column(Float)
    confidence_threshold: Mapped[float | None] = mapped_column(Float, default=None)
    prior_mean: Mapped[FloatArray] = mapped_column(FloatArrayType)
    prior_cov: Mapped[FloatArray] = mapped_column(FloatArrayType)
    action_lower: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    action_upper: Mapped[FloatArray | None] = mapped_column(FloatArrayType, default=None)
    target: Mapped[str | None] = mapped_column(String(200), default=None)
    seed: Mapped[int | None] = mapped_column(Integer, default=None)
    options: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    result_object: Mapped[str | None] = mapped_column(String(200), default=None)
    result_correct: Mapped[bool | None] = mapped_column(Boolean, default=None)
    n_steps: Mapped[int] = mapped_column(Integer, default=0)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)

    model: Mapped[ModelRecord] = relationship()
    steps: Mapped[list[TrialStep]] = relationship(
        back_populates="trial", cascade="all, delete-orphan", order_by="TrialStep.step"
    )


class TrialStep(Base):
    """One touch of a trial and the belief after it; committed the moment it happens."""

    __tablename__ = "trial_steps"
    __table_args__ = (UniqueConstraint("trial_id", "step"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"))
    step: Mapped[int] = mapped_column(Integer)
    action: Mapped[FloatArray] = mapped_column(FloatArrayType)
    observation: Mapped[FloatArray] = mapped_column(FloatArrayType)
    trajectory: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    mutual_information: Mapped[float | None] = mapped_column(Float, default=None)
    belief_mean: Mapped[FloatArray] = mapped_column(FloatArrayType)
    belief_cov: Mapped[FloatArray] = mapped_column(FloatArrayType)
    probabilities: Mapped[FloatArray] = mapped_column(FloatArrayType)
    nearest_object: Mapped[str] = mapped_column(String(200))
    answer: Mapped[str] = mapped_column(String(200))
    stop_reason: Mapped[str | None] = mapped_column(String(20), default=None)
    duration_s: Mapped[float] = mapped_column(Float, default=0.0)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)

    trial: Mapped[Trial] = relationship(back_populates="steps")


class Run(Base):
    """A long job on the rig (a data collection) with state and progress."""

    __tablename__ = "runs"

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(String(20))  # collection
    status: Mapped[str] = mapped_column(String(20), default="queued")
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    done: Mapped[int] = mapped_column(Integer, default=0)
    total: Mapped[int] = mapped_column(Integer, default=0)
    dataset_id: Mapped[int | None] = mapped_column(ForeignKey("datasets.id"), default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)


class EventRecord(Base):
    """A server-sent event; ``id`` is its sequence number (never reused)."""

    __tablename__ = "events"
    __table_args__ = ({"sqlite_autoincrement": True},)

    id: Mapped[int] = mapped_column(primary_key=True)
    type: Mapped[str] = mapped_column(String(50))
    data: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)


class Evaluation(Base):
    """A policy evaluation job: its request, state, progress and final summary.

    ``spec`` is the request as the API received it (``EvaluationCreate``); ``steps`` the T
    actually run (fewer than asked when a replay pool caps it); ``summary`` is the
    ``activetouch-evaluation/2`` document of the finished report without its ``trials`` (those
    are :class:`EvaluationTrial` rows, written as each trial finishes); ``workers`` is the
    number asked for until the report says how many ran trials.
    """

    __tablename__ = "evaluations"

    id: Mapped[int] = mapped_column(primary_key=True)
    model_id: Mapped[int] = mapped_column(ForeignKey("models.id"), index=True)
    dataset_id: Mapped[int | None] = mapped_column(ForeignKey("datasets.id"), default=None)
    spec: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    status: Mapped[str] = mapped_column(String(20), default="queued", index=True)
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    done: Mapped[int] = mapped_column(Integer, default=0)
    total: Mapped[int] = mapped_column(Integer, default=0)
    steps: Mapped[int] = mapped_column(Integer)  # T run: the request's, or a replay pool's cap
    workers: Mapped[int | None] = mapped_column(Integer, default=None)
    seconds: Mapped[float | None] = mapped_column(Float, default=None)
    summary: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now, onupdate=utc_now)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, default=None)


class EvaluationTrial(Base):
    """One finished trial of an evaluation: its ``TrialRecord`` as JSON (``record``).

    ``number`` counts the trials in the order they finished (1, 2, ...); (policy, target,
    trial) names the trial as the engine does. ``refused``: the rig refused one of its touches
    (``record`` is then a ``RefusedTrial`` document: ``correct`` false, ``touches`` those
    performed before the refusal, ``refused`` the touch, action and device message).
    """

    __tablename__ = "evaluation_trials"
    __table_args__ = (
        UniqueConstraint("evaluation_id", "number"),
        UniqueConstraint("evaluation_id", "policy", "target", "trial"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    evaluation_id: Mapped[int] = mapped_column(ForeignKey("evaluations.id", ondelete="CASCADE"))
    number: Mapped[int] = mapped_column(Integer)
    policy: Mapped[str] = mapped_column(String(50))
    target: Mapped[str] = mapped_column(String(200))
    trial: Mapped[int] = mapped_column(Integer)
    correct: Mapped[bool] = mapped_column(Boolean)
    touches: Mapped[int] = mapped_column(Integer)
    refused: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    record: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now)


class RequestAudit(Base):
    """A mutating API request (``POST``/``PUT``/``PATCH``/``DELETE``), refused ones included:
    when, from which address, what, the outcome, and whether (and how) it authenticated."""

    __tablename__ = "request_audit"

    id: Mapped[int] = mapped_column(primary_key=True)
    time: Mapped[datetime] = mapped_column(UTCDateTime, default=utc_now, index=True)
    client: Mapped[str | None] = mapped_column(String(100), default=None)
    method: Mapped[str] = mapped_column(String(10))
    path: Mapped[str] = mapped_column(String(500))
    route: Mapped[str | None] = mapped_column(String(200), default=None)
    status_code: Mapped[int] = mapped_column(Integer)
    authenticated: Mapped[bool] = mapped_column(Boolean)
    auth_method: Mapped[str | None] = mapped_column(String(20), default=None)
    duration_ms: Mapped[float] = mapped_column(Float)
