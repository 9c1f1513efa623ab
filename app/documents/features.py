"""The model document's ``features`` field: the feature pipeline a model applies to a raw touch.

Absent (documents written before raw touches, or models fitted on a training CSV) means y is
given as it is — the channel means of a rig touch. Present, it holds the pipeline's kind, its
channel layout and, for ``"whole"``, its settings and fitted standardisation and PCA axes, and
how dy was chosen (``selection``, like ``latent_selection``), so that every consumer of the
model (rig, replay, scripted trials, 3D view) computes exactly the same y.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from app.documents.errors import DocumentError
from core.errors import InvalidInputError
from core.features.pipeline import (
    FEATURE_KINDS,
    ChannelPlan,
    FeatureDimScore,
    FeaturePipeline,
    FeatureSelection,
    FeatureSettings,
)


def feature_selection_dict(selection: FeatureSelection) -> dict[str, Any]:
    """How dy was chosen, as JSON."""
    return {
        "chosen": selection.chosen,
        "projection": selection.projection,
        "best": selection.best,
        "best_projection": selection.best_projection,
        "n_folds": selection.n_folds,
        "criterion": "share of held-out touches recognised (pooled-covariance Gaussian)",
        "candidates": [dataclasses.asdict(c) for c in selection.candidates],
        "explanation": selection.explanation,
    }


def features_field(pipeline: FeaturePipeline) -> dict[str, Any]:
    """The ``features`` field of a model document."""
    field: dict[str, Any] = {
        "kind": pipeline.kind,
        "channels": [
            {
                "name": p.name,
                "role": p.role,
                "width": p.width,
                "band_edges_hz": list(p.band_edges_hz),
            }
            for p in pipeline.channels
        ],
        "reduced_names": list(pipeline.reduced_names),
        "output_names": list(pipeline.output_names),
    }
    if pipeline.kind == "whole":
        assert pipeline.center is not None and pipeline.scale is not None  # noqa: PT018
        assert pipeline.components is not None and pipeline.explained_variance is not None  # noqa: PT018
        field.update(
            projection=pipeline.projection,
            settings=dataclasses.asdict(pipeline.settings),
            center=pipeline.center.tolist(),
            scale=pipeline.scale.tolist(),
            components=pipeline.components.tolist(),
            explained_variance=pipeline.explained_variance.tolist(),
        )
    if pipeline.selection is not None:
        field["selection"] = feature_selection_dict(pipeline.selection)
    return field


def _selection(value: Any) -> FeatureSelection | None:
    if value is None:
        return None
    return FeatureSelection(
        chosen=int(value["chosen"]),
        projection=value["projection"],
        best=int(value["best"]),
        best_projection=value["best_projection"],
        n_folds=int(value["n_folds"]),
        candidates=tuple(
            FeatureDimScore(
                feature_dim=int(c["feature_dim"]),
                projection=c["projection"],
                fold_scores=tuple(float(v) for v in c["fold_scores"]),
                mean=float(c["mean"]),
                standard_error=float(c["standard_error"]),
                difference=float(c["difference"]),
                difference_standard_error=float(c["difference_standard_error"]),
            )
            for c in value["candidates"]
        ),
        explanation=str(value["explanation"]),
    )


def read_features_field(value: Any, observation_dim: int) -> FeaturePipeline | None:
    """The pipeline of a ``features`` field (``None`` when the field is absent).

    Raises:
        DocumentError: A malformed field, or a pipeline whose output length is not the
            model's dy.
    """
    if value is None:
        return None
    if not isinstance(value, Mapping) or value.get("kind") not in FEATURE_KINDS:
        raise DocumentError(
            f"model document: 'features.kind' must be one of {list(FEATURE_KINDS)}.",
            column="features",
        )
    try:
        channels = tuple(
            ChannelPlan(
                name=str(c["name"]),
                role=c["role"],
                width=int(c["width"]),
                band_edges_hz=tuple(float(v) for v in c.get("band_edges_hz", [])),
            )
            for c in value["channels"]
        )
        names = tuple(str(n) for n in value["reduced_names"])
        arrays: dict[str, Any] = {}
        settings = FeatureSettings()
        if value["kind"] == "whole":
            settings = FeatureSettings(**value["settings"])
            arrays = {
                "projection": value.get("projection", "pca"),
                **{
                    name: np.asarray(value[name], dtype=np.float64)
                    for name in ("center", "scale", "components", "explained_variance")
                },
            }
        pipeline = FeaturePipeline(
            value["kind"],
            channels,
            names,
            settings,
            selection=_selection(value.get("selection")),
            **arrays,
        )
    except (KeyError, TypeError, ValueError, InvalidInputError) as exc:
        raise DocumentError(
            f"model document: malformed field 'features' ({exc}).", column="features"
        ) from exc
    if pipeline.output_dim != observation_dim:
        raise DocumentError(
            f"model document: 'features' gives {pipeline.output_dim} features, the model has "
            f"observation_dim {observation_dim}.",
            column="features",
        )
    return pipeline
