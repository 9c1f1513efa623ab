"""Datasets: upload (CSV or JSON), read, export, and load as :class:`core.types.TrainingData`."""

from __future__ import annotations

import dataclasses
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app import crud
from app.db.tables import Dataset
from app.documents.raw_touches import (
    channels_field,
    featurise,
    frames_touch,
    line_refusal,
    read_raw_touches,
    stored_touch,
)
from app.documents.training_csv import TrainingCsvWriter, read_training_csv
from app.errors import BadInputError, ConflictError
from app.schemas import DatasetCreate, DatasetPublic, Page, SampleIn, from_row
from app.services.events import EventBus
from core.errors import InvalidInputError
from core.features.pipeline import FeatureKind, FeaturePipeline, check_touches, means_pipeline
from core.features.raw import RawTouch
from core.types import TrainingData
from core.validation import FloatArray, IntArray


def to_public(dataset: Dataset) -> DatasetPublic:
    """The API view of a dataset row."""
    return from_row(DatasetPublic, dataset, objects=list(dataset.object_names))


def placement_index(placements: Sequence[int | None]) -> IntArray | None:
    """The samples' placement numbers as ``TrainingData.placement_index``: ``None`` unless
    every sample recorded one (a dataset either records placements or does not)."""
    if not placements or any(p is None for p in placements):
        return None
    return np.asarray(placements, dtype=np.int64)


def touch_times(times_s: Sequence[float | None]) -> FloatArray | None:
    """The samples' times as ``TrainingData.touch_times_s`` (seconds): ``None`` unless every
    sample recorded one (a dataset either records when its touches were made or does not)."""
    if not times_s or any(t is None for t in times_s):
        return None
    return np.asarray(times_s, dtype=np.float64)


def store_training_data(
    session: Session,
    data: TrainingData,
    name: str,
    source: str,
    raw: Sequence[dict[str, Any]] | None = None,
) -> Dataset:
    """Add a complete dataset holding ``data`` (not committed), with each touch's placement
    and time, and the touches' duration, when ``data`` records them.

    ``raw``: each sample's raw record (its channels), kept so it can be featurised again.
    """
    dataset = crud.create_dataset(
        session,
        name=name,
        source=source,
        status="ready",
        object_names=data.object_names,
        action_dim=data.action_dim,
        observation_dim=data.observation_dim,
        touch_duration_s=data.touch_duration_s,
    )
    records: Sequence[dict[str, Any] | None] = (
        [None] * len(data.object_index) if raw is None else raw
    )
    placements: list[int | None] = (
        [None] * len(data.object_index)
        if data.placement_index is None
        else [int(p) for p in data.placement_index]
    )
    times_s: list[float | None] = (
        [None] * len(data.object_index)
        if data.touch_times_s is None
        else [float(t) for t in data.touch_times_s]
    )
    crud.add_samples(
        session,
        dataset,
        (
            (data.object_names[obj], action, observation, record, placement, time_s)
            for obj, action, observation, record, placement, time_s in zip(
                data.object_index,
                data.actions,
                data.observations,
                records,
                placements,
                times_s,
                strict=True,
            )
        ),
    )
    return dataset


def _commit_and_announce(
    session: Session,
    events: EventBus,
    data: TrainingData,
    name: str,
    source: str,
    raw: Sequence[dict[str, Any]] | None = None,
) -> DatasetPublic:
    dataset = store_training_data(session, data, name, source, raw)
    session.commit()
    public = to_public(dataset)
    events.publish(
        "dataset.created",
        {"dataset_id": public.id, "n_samples": public.n_samples, "objects": public.objects},
    )
    return public


def create_from_csv(session: Session, events: EventBus, text: str, name: str) -> DatasetPublic:
    """Parse a training CSV and store it.

    Raises:
        app.documents.errors.DocumentError: (→ 422) the message names the row and column.
    """
    data = read_training_csv(text)
    return _commit_and_announce(session, events, data, name, "upload")


def training_data_from_samples(
    samples: list[SampleIn], touch_duration_s: float | None = None
) -> TrainingData:
    """Check a JSON upload's samples and build training data (their touches lasted
    ``touch_duration_s``, when recorded).

    Raises:
        BadInputError: Ragged action/observation lengths (naming ``samples[i].field``), a
            placement or time given for some samples but not for all (``samples[i].placement``,
            ``samples[i].time_s``), fewer than 2 objects or an object with fewer than 2 samples.
    """
    first = samples[0]
    dx, dy = len(first.action), len(first.observation)
    names: list[str] = []
    index: list[int] = []
    for i, sample in enumerate(samples):
        for field, what in (("placement", "a placement"), ("time_s", "a time")):
            given, first_given = getattr(sample, field), getattr(first, field)
            if (given is None) != (first_given is None):
                raise BadInputError(
                    f"samples[{i}].{field}: "
                    + ("missing" if given is None else "given")
                    + f", but samples[0].{field} is "
                    + ("not" if first_given is None else "given")
                    + f"; give every sample {what} or none.",
                    field=f"samples[{i}].{field}",
                )
        for field, values, expected in (
            ("action", sample.action, dx),
            ("observation", sample.observation, dy),
        ):
            if len(values) != expected:
                raise BadInputError(
                    f"samples[{i}].{field}: has {len(values)} values, but samples[0].{field} "
                    f"has {expected}; every sample needs the same length.",
                    field=f"samples[{i}].{field}",
                )
        if sample.object not in names:
            names.append(sample.object)
        index.append(names.index(sample.object))
    try:
        return TrainingData(
            object_names=tuple(names),
            object_index=np.asarray(index, dtype=np.int64),
            actions=np.asarray([s.action for s in samples], dtype=np.float64),
            observations=np.asarray([s.observation for s in samples], dtype=np.float64),
            placement_index=placement_index([s.placement for s in samples]),
            touch_times_s=touch_times([s.time_s for s in samples]),
            touch_duration_s=touch_duration_s,
        )
    except InvalidInputError as exc:
        raise BadInputError(f"samples: {exc}", field="samples") from exc


@dataclass(frozen=True)
class RawUpload:
    """Raw touches checked and ready to store: their training data (y: each channel's mean) and
    each touch's channels."""

    data: TrainingData
    raw: list[dict[str, Any]]


def read_raw_upload(text: str, features: FeatureKind = "whole") -> RawUpload:
    """Read and check a raw-touch file (``docs/raw-touches.md``) for storing.

    Args:
        text: The file.
        features: The pipeline the touches are meant for: with ``"whole"`` every series must
            be at least its window long (:func:`core.features.pipeline.check_touches`).

    Raises:
        app.documents.errors.DocumentError: (→ 422) the message names the line and channel.
    """
    touches = read_raw_touches(text)
    try:
        check_touches(touches.touches, features)
    except InvalidInputError as exc:
        raise line_refusal(touches, exc) from None
    data = featurise(touches, means_pipeline(touches.touches[0]))
    return RawUpload(data, [{"channels": channels_field(touch)} for touch in touches.touches])


def store_raw_upload(
    session: Session, events: EventBus, upload: RawUpload, name: str, source: str = "upload"
) -> DatasetPublic:
    """Store checked raw touches (:func:`read_raw_upload`) as one dataset, committed at once:
    y is each channel's mean, and every touch's channels are kept with its sample, so the
    dataset can be featurised again (:func:`featurised_data`, :func:`export_raw`) without
    touching the objects again."""
    return _commit_and_announce(session, events, upload.data, name, source, upload.raw)


def create_from_raw(
    session: Session,
    events: EventBus,
    text: str,
    name: str,
    features: FeatureKind = "whole",
) -> DatasetPublic:
    """Check raw touches (:func:`read_raw_upload`) and store them (:func:`store_raw_upload`).

    Raises:
        app.documents.errors.DocumentError: (→ 422) the message names the line and channel;
            nothing is stored.
    """
    return store_raw_upload(session, events, read_raw_upload(text, features), name)


def export_raw(session: Session, dataset_id: int) -> str:
    """The dataset's raw touches as a raw-touch file (JSON lines).

    Samples uploaded as raw touches keep their channels; samples a rig collection recorded
    keep their frames, regrouped into channels by name (``docs/raw-touches.md``). A sample
    that recorded its placement writes it as the line's ``placement``, one that recorded its
    time as the line's ``time_s``, and a dataset that recorded its touches' duration writes it
    as every line's ``duration_s``.

    Raises:
        BadInputError: (→ 422) a sample without its raw series (uploaded as y only).
    """
    dataset = require(session, dataset_id)
    lines = []
    for k, (name, action, raw, placement, time_s) in enumerate(
        crud.dataset_raw_samples(session, dataset.id)
    ):
        if raw is not None and "channels" in raw:
            channels = raw["channels"]
        elif raw is not None and "tactile" in raw:
            channels = channels_field(frames_touch(raw))
        else:
            raise BadInputError(
                f"Dataset {dataset_id}: sample {k + 1} has no raw series (it was uploaded as "
                "y only); only raw touches or rig collections can be exported raw.",
                field="dataset_id",
            )
        line: dict[str, Any] = {"object": name, "action": action.tolist(), "channels": channels}
        if placement is not None:
            line["placement"] = placement
        if time_s is not None:
            line["time_s"] = time_s
        if dataset.touch_duration_s is not None:
            line["duration_s"] = dataset.touch_duration_s
        lines.append(json.dumps(line))
    return "".join(line + "\n" for line in lines)


def create_from_json(session: Session, events: EventBus, body: DatasetCreate) -> DatasetPublic:
    """Store a JSON upload."""
    data = training_data_from_samples(body.samples, body.touch_duration_s)
    return _commit_and_announce(session, events, data, body.name, "upload")


require = partial(crud.require, Dataset)


def get(session: Session, dataset_id: int) -> DatasetPublic:
    """One dataset's summary."""
    return to_public(require(session, dataset_id))


def list_page(session: Session, limit: int, offset: int) -> Page[DatasetPublic]:
    """Datasets, newest first."""
    rows, count = crud.list_datasets(session, limit, offset)
    return Page[DatasetPublic](data=[to_public(r) for r in rows], count=count)


def load_training_data(session: Session, dataset_id: int) -> TrainingData:
    """The dataset's touches as training data.

    Raises:
        NotFoundError: No such dataset.
        ConflictError: The dataset is still being collected (or its collection failed).
        BadInputError: It cannot make training data (e.g. an interrupted collection).
    """
    dataset = require(session, dataset_id)
    if dataset.status != "ready":
        raise ConflictError(
            f"Dataset {dataset_id} is {dataset.status}; only a ready dataset can be used.",
            current_state=dataset.status,
        )
    return _training_data(session, dataset)


def training_data(session: Session, dataset_id: int) -> TrainingData:
    """A dataset's touches as training data, whatever its status."""
    return _training_data(session, require(session, dataset_id))


def _training_data(session: Session, dataset: Dataset) -> TrainingData:
    """The samples as training data, with ``placement_index`` when every sample recorded its
    placement (the fit then estimates the placement effect), ``touch_times_s`` when every
    sample recorded its time (the drift shared by touches made close together,
    :mod:`core.gp.drift_effect`) and ``touch_duration_s`` when the dataset recorded it."""
    rows = crud.dataset_samples(session, dataset.id)
    names = list(dataset.object_names)
    position = {name: i for i, name in enumerate(names)}
    try:
        return TrainingData(
            object_names=tuple(names),
            object_index=np.asarray([position[row[0]] for row in rows], dtype=np.int64),
            actions=np.asarray([row[1] for row in rows], dtype=np.float64).reshape(
                len(rows), dataset.action_dim
            ),
            observations=np.asarray([row[2] for row in rows], dtype=np.float64).reshape(
                len(rows), dataset.observation_dim
            ),
            placement_index=placement_index([row[3] for row in rows]),
            touch_times_s=touch_times([row[4] for row in rows]),
            touch_duration_s=dataset.touch_duration_s,
        )
    except InvalidInputError as exc:
        raise BadInputError(
            f"Dataset {dataset.id} cannot be used as training data: {exc}",
            field="dataset_id",
        ) from exc


def raw_touches(session: Session, dataset_id: int) -> tuple[TrainingData, list[RawTouch]]:
    """A dataset's touches with their raw series, to be featurised again.

    Returns:
        The stored training data (y as stored) and each sample's raw touch, in order.

    Raises:
        BadInputError: (→ 422, field ``features``) a sample without raw series (uploaded as y
            only) or whose series cannot be read, or touches of different channel layouts;
            the message names the sample.
    """
    dataset = require(session, dataset_id)
    data = _training_data(session, dataset)
    touches: list[RawTouch] = []
    for k, (_, _, raw, *_) in enumerate(crud.dataset_raw_samples(session, dataset.id), start=1):
        if raw is None:
            raise BadInputError(
                f"features: dataset {dataset_id}, sample {k} has no raw series (it was uploaded "
                "as y only); features are made of raw touches — upload them as "
                "application/x-ndjson (docs/raw-touches.md) or collect them on the rig.",
                field="features",
            )
        try:
            touches.append(stored_touch(raw))
        except InvalidInputError as exc:
            raise BadInputError(
                f"features: dataset {dataset_id}, sample {k}: {exc}", field="features"
            ) from None
    return data, touches


def has_raw_touches(session: Session, dataset_id: int) -> bool:
    """Whether every sample of the dataset keeps its raw series."""
    rows = crud.dataset_raw_samples(session, dataset_id)
    return bool(rows) and all(raw is not None for _, _, raw, *_ in rows)


def featurised_data(session: Session, dataset_id: int, pipeline: FeaturePipeline) -> TrainingData:
    """The dataset's touches with y made by ``pipeline`` from their raw series.

    Raises:
        BadInputError: (→ 422, field ``features``) a sample without raw series, or one the
            pipeline refuses (another channel set, a series shorter than its window), named.
    """
    data, touches = raw_touches(session, dataset_id)
    try:
        y = pipeline.transform_many(touches)
    except InvalidInputError as exc:
        raise BadInputError(
            f"features: dataset {dataset_id}, {str(exc).replace('touch ', 'sample ', 1)}",
            field="features",
        ) from None
    return dataclasses.replace(data, observations=y)


def export_csv(session: Session, dataset_id: int) -> str:
    """The dataset as training CSV (floats written with ``repr``: exact round trip), with the
    ``placement`` column when every sample recorded its placement, the ``time_s`` column
    when every sample recorded its time and the ``duration_s`` column when the dataset recorded
    its touches' duration.

    Written touch by touch by :class:`app.documents.training_csv.TrainingCsvWriter`, so a
    partial dataset (a collection in progress or interrupted, which is not yet training data)
    exports in the same format as a ready one.
    """
    dataset = require(session, dataset_id)
    rows = crud.dataset_samples(session, dataset.id)
    placed = placement_index([row[3] for row in rows]) is not None
    timed = touch_times([row[4] for row in rows]) is not None
    out = io.StringIO()
    writer = TrainingCsvWriter(
        out,
        dataset.action_dim,
        dataset.observation_dim,
        placements=placed,
        times=timed,
        duration_s=dataset.touch_duration_s,
    )
    for name, action, observation, placement, time_s in rows:
        writer.write(
            name, action, observation, placement if placed else None, time_s if timed else None
        )
    return out.getvalue()


def export_json(session: Session, dataset_id: int) -> DatasetCreate:
    """The dataset in the JSON upload format (each sample's ``placement`` when every sample
    recorded one, its ``time_s`` likewise, and the touches' duration when recorded)."""
    dataset = require(session, dataset_id)
    rows = crud.dataset_samples(session, dataset.id)
    placed = placement_index([row[3] for row in rows]) is not None
    timed = touch_times([row[4] for row in rows]) is not None
    return DatasetCreate(
        name=dataset.name,
        touch_duration_s=dataset.touch_duration_s,
        samples=[
            SampleIn(
                object=name,
                action=action.tolist(),
                observation=observation.tolist(),
                placement=placement if placed else None,
                time_s=time_s if timed else None,
            )
            for name, action, observation, placement, time_s in rows
        ],
    )
