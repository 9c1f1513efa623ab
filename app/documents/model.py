"""The model document ("activetouch-model/1"): a self-contained JSON object from which the model can
be reloaded and used to predict, plan and recognise.

The training data are included; β and K⁻¹ are recomputed on load, conditioned as the
``posterior`` field recorded (:mod:`app.documents.posterior`) in the observation transform of the
``noise_model`` field (:mod:`app.documents.noise_model`). ``latent_selection`` (optional) reports
how ``--latent-dim auto`` chose ds. ``features`` (optional, :mod:`app.documents.features`) is the
pipeline that turns a raw touch into y; without it y is the channel means.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from app.documents.errors import DocumentError
from app.documents.features import features_field, read_features_field
from app.documents.noise_model import noise_model_field, read_noise_model_field
from app.documents.posterior import condition_as_recorded, posterior_field
from core.errors import InvalidInputError
from core.latent_selection import LatentSelection
from core.types import FitDiagnostics, Hyperparameters, ManifoldModel, TrainingData

MODEL_FORMAT = "activetouch-model/1"


def latent_selection_dict(selection: LatentSelection) -> dict[str, Any]:
    """A latent-dimension selection as JSON (the model document's ``latent_selection``)."""
    return {
        "chosen": selection.chosen,
        "best": selection.best,
        "n_folds": selection.n_folds,
        "candidates": [
            {
                "latent_dim": c.latent_dim,
                "mean": c.mean,
                "standard_error": c.standard_error,
                "difference": c.difference,
                "difference_standard_error": c.difference_standard_error,
                "fold_scores": list(c.fold_scores),
            }
            for c in selection.candidates
        ],
        "explanation": selection.explanation,
    }


def model_to_document(
    model: ManifoldModel,
    fit_seconds: float | None = None,
    latent_selection: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The model document (format ``activetouch-model/1``) as a JSON-ready dict.

    Args:
        model: The model; its raw training data are written, and its observation transform
            as ``noise_model``.
        fit_seconds: How long the fit took.
        latent_selection: How ``latent_dim="auto"`` chose ds, if it did (written as is).
    """
    h = model.hyperparameters
    data = model.raw_data
    document: dict[str, Any] = {
        "format": MODEL_FORMAT,
        "latent_dim": model.latent_dim,
        "action_dim": data.action_dim,
        "observation_dim": data.observation_dim,
        "objects": [
            {"name": name, "latent": [float(v) for v in latent]}
            for name, latent in zip(data.object_names, model.latents, strict=True)
        ],
        "hyperparameters": [
            {
                "signal_variance": float(h.signal_variance[a]),
                "noise_variance": float(h.noise_variance[a]),
                "latent_lengthscales": [float(v) for v in h.latent_lengthscales[a]],
                "action_lengthscales": [float(v) for v in h.action_lengthscales[a]],
            }
            for a in range(h.observation_dim)
        ],
        "log_likelihood": float(model.log_likelihood),
        "fit_seconds": None if fit_seconds is None else float(fit_seconds),
        "posterior": posterior_field(model.posterior),
        "training_data": {
            "objects": [data.object_names[i] for i in data.object_index],
            "actions": data.actions.tolist(),
            "observations": data.observations.tolist(),
        },
    }
    noise = noise_model_field(model.transform)
    if noise is not None:
        document["noise_model"] = noise
    if latent_selection is not None:
        document["latent_selection"] = dict(latent_selection)
    if model.features is not None:
        document["features"] = features_field(model.features)
    if model.diagnostics is not None:
        d = model.diagnostics
        document["diagnostics"] = {
            "starts_log_likelihood": list(d.starts_log_likelihood),
            "best_start": d.best_start,
            "iterations": d.iterations,
            "converged": d.converged,
            "message": d.message,
            "jitter_used": d.jitter_used,
            "hyperparameters_at_bounds": list(d.hyperparameters_at_bounds),
        }
    return document


def _field(document: Mapping[str, Any], name: str, where: str = "model document") -> Any:
    if name not in document:
        raise DocumentError(f"{where}: missing field {name!r}.", column=name)
    return document[name]


def model_from_document(document: Any) -> ManifoldModel:
    """Rebuild a :class:`ManifoldModel` from its document (re-conditioning the GP).

    Raises:
        DocumentError: Wrong format tag, missing fields, or inconsistent dimensions (the
            message names the field).
    """
    if not isinstance(document, Mapping):
        raise DocumentError("model document: expected a JSON object.")
    if _field(document, "format") != MODEL_FORMAT:
        raise DocumentError(
            f"model document: format must be {MODEL_FORMAT!r}, found {document['format']!r}.",
            column="format",
        )
    objects = _field(document, "objects")
    training = _field(document, "training_data")
    hyper = _field(document, "hyperparameters")
    try:
        names = [str(o["name"]) for o in objects]
        latents = np.asarray([o["latent"] for o in objects], dtype=np.float64)
        touch_objects = [str(n) for n in _field(training, "objects", "training_data")]
        unknown = sorted(set(touch_objects) - set(names))
        if unknown:
            raise DocumentError(
                f"training_data.objects: names {unknown} are not in 'objects'.",
                column="training_data.objects",
            )
        data = TrainingData(
            object_names=tuple(names),
            object_index=np.asarray([names.index(n) for n in touch_objects], dtype=np.int64),
            actions=np.asarray(_field(training, "actions", "training_data"), dtype=np.float64),
            observations=np.asarray(
                _field(training, "observations", "training_data"), dtype=np.float64
            ),
        )
        hyperparameters = Hyperparameters(
            signal_variance=np.asarray([f["signal_variance"] for f in hyper], dtype=np.float64),
            noise_variance=np.asarray([f["noise_variance"] for f in hyper], dtype=np.float64),
            latent_lengthscales=np.asarray(
                [f["latent_lengthscales"] for f in hyper], dtype=np.float64
            ),
            action_lengthscales=np.asarray(
                [f["action_lengthscales"] for f in hyper], dtype=np.float64
            ),
        )
    except DocumentError:
        raise
    except InvalidInputError as exc:
        raise DocumentError(f"model document: {exc}") from exc
    except (KeyError, TypeError, ValueError) as exc:
        raise DocumentError(f"model document: malformed field ({exc!r}).") from exc
    for name, expected, actual in (
        ("latent_dim", hyperparameters.latent_dim, document.get("latent_dim")),
        ("action_dim", data.action_dim, document.get("action_dim")),
        ("observation_dim", data.observation_dim, document.get("observation_dim")),
    ):
        if actual is not None and actual != expected:
            raise DocumentError(
                f"model document: {name} is {actual} but the arrays say {expected}.", column=name
            )
    diagnostics = None
    if isinstance(document.get("diagnostics"), Mapping):
        d = document["diagnostics"]
        try:
            diagnostics = FitDiagnostics(
                starts_log_likelihood=tuple(float(v) for v in d.get("starts_log_likelihood", [])),
                best_start=int(d.get("best_start", 0)),
                iterations=int(d.get("iterations", 0)),
                converged=bool(d.get("converged", False)),
                message=str(d.get("message", "")),
                jitter_used=float(d.get("jitter_used", 0.0)),
                hyperparameters_at_bounds=tuple(
                    str(v) for v in d.get("hyperparameters_at_bounds", [])
                ),
            )
        except (TypeError, ValueError) as exc:
            raise DocumentError(
                f"model document: malformed field 'diagnostics' ({exc}).", column="diagnostics"
            ) from exc
    transform = read_noise_model_field(document.get("noise_model"), data.observation_dim)
    features = read_features_field(document.get("features"), data.observation_dim)
    model = condition_as_recorded(
        data, latents, hyperparameters, diagnostics, document.get("posterior"), transform=transform
    )
    return model if features is None else dataclasses.replace(model, features=features)
