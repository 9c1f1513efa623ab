"""Touches for ``fit`` and ``evaluate --world replay``: a training CSV or a raw-touch file.

A file whose first non-blank character is ``{`` is a raw-touch file (JSON lines,
``docs/raw-touches.md``); anything else is a training CSV. Raw touches are featurised by the
pipeline being fitted (``fit``) or by the model's own pipeline (replay).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

from app.cli.output import fail, read_text

if TYPE_CHECKING:
    from app.documents.raw_touches import RawTouchSet
    from core.features.pipeline import FeaturePipeline
    from core.types import ManifoldModel, TrainingData

FeaturesName = Literal["means", "whole"]


def is_raw_touches(text: str) -> bool:
    """Whether ``text`` is a raw-touch file rather than a training CSV."""
    return text.lstrip().startswith("{")


def _read(path: Path, option: str) -> str:
    return read_text(path, option.rstrip(": "))


def _raw(text: str, path: Path, option: str) -> RawTouchSet:
    from app.documents.raw_touches import read_raw_touches
    from core.errors import CoreError

    try:
        return read_raw_touches(text)
    except CoreError as exc:
        raise fail(f"{option}{path}: {exc}") from None


def training_touches(
    path: Path, features: FeaturesName | None, feature_dim: int | None, seed: int
) -> tuple[TrainingData, FeaturePipeline | None]:
    """The training data of ``fit`` and the feature pipeline fitted to them.

    Args:
        path: A training CSV or a raw-touch file.
        features: ``"means"`` or ``"whole"``; ``None``: whole for raw touches, as given for a CSV.
        feature_dim: dy of the whole pipeline; ``None`` chooses it by cross-validation.
        seed: Seed of that cross-validation.

    Raises:
        typer.Exit: (code 2) an unreadable or bad file (naming line and channel), or
            ``--features whole`` with a CSV, which holds no series.
    """
    from app.documents.raw_touches import featurise, line_refusal
    from app.documents.training_csv import read_training_csv
    from core.errors import CoreError, InvalidInputError
    from core.features.pipeline import fit_features

    text = _read(path, "")
    if not is_raw_touches(text):
        if features == "whole":
            raise fail(
                f"--features whole: {path} is a training CSV (one y per touch); whole-touch "
                "features need a raw-touch file (docs/raw-touches.md)."
            )
        try:
            return read_training_csv(text), None
        except CoreError as exc:
            raise fail(str(exc)) from None
    touches = _raw(text, path, "")
    try:
        pipeline = fit_features(
            touches.touches,
            touches.object_index,
            features or "whole",
            feature_dim=feature_dim,
            seed=seed,
        )
    except InvalidInputError as exc:
        raise fail(f"{path}: {line_refusal(touches, exc)}") from None
    try:
        return featurise(touches, pipeline), pipeline
    except CoreError as exc:
        raise fail(f"{path}: {exc}") from None


def replay_touches(path: Path, model: ManifoldModel) -> TrainingData:
    """Held-out touches of a replay, as the model sees them.

    A raw-touch file goes through the model's feature pipeline (the channel means for a model
    without one); a training CSV is taken as it is.

    Raises:
        typer.Exit: (code 2) an unreadable or bad file, or touches the pipeline refuses.
    """
    from app.documents.raw_touches import featurise
    from app.documents.training_csv import read_training_csv
    from core.errors import CoreError
    from core.features.pipeline import means_pipeline

    text = _read(path, "--data: ")
    try:
        if not is_raw_touches(text):
            return read_training_csv(text)
        touches = _raw(text, path, "--data ")
        pipeline = model.features or means_pipeline(touches.touches[0])
        return featurise(touches, pipeline)
    except CoreError as exc:
        raise fail(f"--data {path}: {exc}") from None


def features_summary(pipeline: FeaturePipeline) -> str:
    """One line on a model's features: kind, dy, and how dy was chosen."""
    if pipeline.kind == "means":
        return f"features: channel means ({pipeline.output_dim} features)"
    text = (
        f"features: whole touch, {len(pipeline.reduced_names)} reduced features of "
        f"{len(pipeline.channels)} channels → PCA dy = {pipeline.output_dim}"
    )
    if pipeline.selection is not None:
        text += f"; {pipeline.selection.explanation}"
    return text
