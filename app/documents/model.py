"""The model document ("activetouch-model/1"): a self-contained JSON object from which the model can
be reloaded and used to predict, plan and recognise.

The training data are included; β and K⁻¹ are recomputed on load, conditioned as the
``posterior`` field recorded (:mod:`app.documents.posterior`) in the observation transform of the
``noise_model`` field (:mod:`app.documents.noise_model`). ``latent_selection`` (optional) reports
how ``--latent-dim auto`` chose ds. ``placement_effect`` (optional) holds σ_b², the variance of
the offset shared by one placement's touches (docs/calibration.md), estimated at fit time from
``training_data.placements`` (optional, the placement number of every touch; ``times_s``, also
optional, when each touch was made; ``duration_s``, also optional, how long every touch lasted as
planned, which recognition on the rig touches with); a document without
it scores a trial's touches as independent (σ_b² = 0); its ``by_object`` (optional, L × dy) holds
each object's own σ_b,l² (:mod:`core.gp.object_placement`), which scores a trial under that
object in place of the pooled σ_b². ``drift_effect`` (optional) holds σ_d²,
the variance of the slow drift a trial's touches share whatever the placement, estimated at fit
time from the training touches' times (:mod:`core.gp.drift_effect`); without it, σ_d² = 0.
``latent_uncertainty`` (optional) holds
the Laplace covariance Σ_l of every object's latent point (docs/method.md (L1)); a document with
it integrates each s_l over N(s_l, Σ_l) in the object likelihood, one without takes s_l as known.
``tempering`` (optional) holds β, the exponent on the object likelihood fitted by cross-validation
on the training touches (:mod:`core.recognition.tempering`, a last resort); without it, β = 1.
``features`` (optional, :mod:`app.documents.features`) is the
pipeline that turns a raw touch into y; without it y is the channel means.
"""

from __future__ import annotations

import dataclasses
import functools
import reprlib
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple, TypeVar

import numpy as np
import numpy.typing as npt

from app.documents.errors import DocumentError
from app.documents.features import features_field, read_features_field
from app.documents.json_values import check_json_values
from app.documents.noise_model import noise_model_field, read_noise_model_field
from app.documents.posterior import condition_as_recorded, posterior_field
from app.documents.training_csv import MAX_NAME_CHARACTERS
from core.errors import InvalidInputError
from core.gp import (
    KERNELS,
    check_drift_variance,
    check_object_placement_variance,
    check_placement_variance,
    check_shift_creep,
    check_shift_variance,
)
from core.recognition import check_exponent, check_latent_covariance
from core.selection import LatentSelection
from core.types import FitDiagnostics, Hyperparameters, ManifoldModel, TrainingData

_T = TypeVar("_T")

MODEL_FORMAT = "activetouch-model/1"

#: Deepest nesting of a list or object a model document has (the document is level 0,
#: ``features.selection.candidates[i].fold_scores`` level 5), and its longest text (an
#: optimizer's message, the latent-selection explanation).
MAX_DOCUMENT_DEPTH = 5
MAX_TEXT_CHARACTERS = 2000
#: Longest list in ``diagnostics`` or ``latent_selection`` (one item a restart or a fold).
MAX_RECORD_ITEMS = 1000


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
    if data.placement_index is not None:
        document["training_data"]["placements"] = data.placement_index.tolist()
    if data.touch_times_s is not None:
        document["training_data"]["times_s"] = data.touch_times_s.tolist()
    if data.touch_duration_s is not None:
        document["training_data"]["duration_s"] = data.touch_duration_s
    document.update(calibration_fields(model))
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
            "kernels": d.kernels,
        }
    return document


def calibration_fields(model: ManifoldModel) -> dict[str, Any]:
    """The optional calibration fields of ``model`` (``placement_effect``, ``drift_effect``,
    ``input_shift``, ``latent_uncertainty``, ``tempering``), each when the model has it: a model
    document's, and a server's model row keeps the same in its posterior record
    (:func:`read_calibrations`)."""
    fields: dict[str, Any] = {}
    if model.placement_variance is not None:
        fields["placement_effect"] = placement_effect_field(
            model.placement_variance, model.placement_in_fit
        )
        if model.object_placement_variance is not None:
            fields["placement_effect"]["by_object"] = model.object_placement_variance.tolist()
    if model.drift_variance is not None:
        fields["drift_effect"] = {
            "variance": [float(v) for v in model.drift_variance],
            "space": "model",
            "estimator": (
                "leave-one-out residuals of touches of different objects made close in time, "
                "method of moments (docs/calibration.md, the drift effect)"
            ),
        }
    if model.shift_variance is not None:
        fields["input_shift"] = {
            "variance": [float(v) for v in model.shift_variance],
            **(
                {}
                if model.shift_creep_variance is None
                else {"creep": [float(v) for v in model.shift_creep_variance]}
            ),
            "space": "action",
            "estimator": (
                "non-negative least squares on the cross-products of leave-one-placement-out "
                "residuals of touches sharing a placement, through the slope of the mean "
                "(docs/calibration.md, the input shift)"
            ),
        }
    if model.latent_covariance is not None:
        fields["latent_uncertainty"] = {
            "covariance": model.latent_covariance.tolist(),
            "method": "Laplace, per object, hyperparameters fixed (docs/method.md (L1))",
        }
    if model.tempering is not None:
        fields["tempering"] = {
            "exponent": float(model.tempering),
            "method": (
                "held-out log-loss of leave-touches-out training trials "
                "(core.recognition.tempering)"
            ),
        }
    return fields


def placement_effect_field(
    variance: npt.NDArray[np.float64], in_fit: bool = False
) -> dict[str, Any]:
    """The ``placement_effect`` field of σ_b² (model space, shape (dy,)): a model document's,
    and a server's model row keeps the same in its posterior record. ``in_fit``: σ_b² is also
    in the training covariance the GP was fitted and conditioned with
    (``in_training_covariance``; the model is then rebuilt with it)."""
    return {
        "variance": [float(v) for v in variance],
        "space": "model",
        "in_training_covariance": bool(in_fit),
        "estimator": (
            "leave-one-placement-out method of moments, refitted with it in the likelihood "
            "(docs/calibration.md)"
            if in_fit
            else "leave-one-placement-out method of moments (docs/calibration.md)"
        ),
    }


def placement_in_fit_variance(
    record: Mapping[str, Any], where: str = "model document"
) -> npt.NDArray[np.float64] | None:
    """σ_b² to condition the GP with, when ``record``'s ``placement_effect`` says it is in the
    training covariance (``in_training_covariance``); ``None`` otherwise (no field, or σ_b² only
    scores trials). Its range is checked when the GP is conditioned.

    Raises:
        DocumentError: (column ``placement_effect``) a flag that is not a boolean, or a variance
            that is not a list of numbers.
    """
    field = record.get("placement_effect")
    if not isinstance(field, Mapping):
        return None
    flag = field.get("in_training_covariance", False)
    if not isinstance(flag, bool):
        raise DocumentError(
            f"{where}: placement_effect.in_training_covariance must be true or false, found "
            f"{reprlib.repr(flag)}.",
            column="placement_effect",
        )
    if not flag:
        return None
    return _array("placement_effect.variance", _field(field, "variance", "placement_effect"))


def read_calibrations(record: Mapping[str, Any], model: ManifoldModel) -> ManifoldModel:
    """``model`` with the calibration fields of ``record`` (a model document or a model row's
    posterior record, :func:`calibration_fields`), each checked against the model.

    Raises:
        DocumentError: (column: the field's name) a malformed field, or a value that does not
            fit the model (e.g. σ_b² of another length than dy or outside [0, σ_n²)).
    """
    for entry in _CALIBRATIONS:
        value = _read_calibration(record, entry, functools.partial(entry.check, model))
        if value is not None:
            model = dataclasses.replace(model, **{entry.attribute: value})
    return model


def _check_number(document: Mapping[str, Any], name: str, minimum: float | None = None) -> None:
    """``document[name]``, when present and not null, is a number (≥ ``minimum``)."""
    value = document.get(name)
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DocumentError(
            f"model document: {name} must be a number, found {type(value).__name__}.",
            column=name,
        )
    if minimum is not None and value < minimum:
        raise DocumentError(
            f"model document: {name} must be ≥ {minimum}, found {value}.", column=name
        )


def _duration_s(value: Any) -> float | None:
    """``training_data.duration_s``: absent (``None``) or a finite number of seconds > 0."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise DocumentError(
            "model document: training_data.duration_s must be a number of seconds > 0, found "
            f"{reprlib.repr(value)}.",
            column="training_data.duration_s",
        )
    return float(value)


def _name(value: Any, where: str) -> str:
    """An object or model name: a non-empty string of at most :data:`MAX_NAME_CHARACTERS`."""
    if not isinstance(value, str) or not value.strip() or len(value) > MAX_NAME_CHARACTERS:
        raise DocumentError(
            f"model document: {where} must be a non-empty name of at most "
            f"{MAX_NAME_CHARACTERS} characters.",
            column=where,
        )
    return value


def _names(values: Any, where: str) -> list[str]:
    """A list of names (:func:`_name`)."""
    if not isinstance(values, list):
        raise DocumentError(f"model document: {where} must be a list of names.", column=where)
    return [_name(value, f"{where}[{i}]") for i, value in enumerate(values)]


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_text(value: Any) -> bool:
    return isinstance(value, str)


def _list_of(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda value: (
        isinstance(value, list)
        and len(value) <= MAX_RECORD_ITEMS
        and all(check(item) for item in value)
    )


#: The fields of the document's ``diagnostics``, ``latent_selection`` and its candidates, as
#: :func:`model_to_document` writes them: name → (what it must be, check).
_Fields = dict[str, tuple[str, Callable[[Any], bool]]]
_DIAGNOSTICS_FIELDS: _Fields = {
    "starts_log_likelihood": (
        f"a list of at most {MAX_RECORD_ITEMS} numbers",
        _list_of(_is_number),
    ),
    "best_start": ("an integer", _is_integer),
    "iterations": ("an integer", _is_integer),
    "converged": ("true or false", lambda value: isinstance(value, bool)),
    "message": ("text", _is_text),
    "jitter_used": ("a number", _is_number),
    "hyperparameters_at_bounds": (
        f"a list of at most {MAX_RECORD_ITEMS} texts",
        _list_of(_is_text),
    ),
    "kernels": (f"one of {', '.join(KERNELS)}", lambda value: value in KERNELS),
}
_LATENT_SELECTION_FIELDS: _Fields = {
    "chosen": ("an integer", _is_integer),
    "best": ("an integer", _is_integer),
    "n_folds": ("an integer", _is_integer),
    "candidates": (
        f"a list of at most {MAX_RECORD_ITEMS}",
        lambda value: isinstance(value, list) and len(value) <= MAX_RECORD_ITEMS,
    ),
    "explanation": ("text", _is_text),
}
_CANDIDATE_FIELDS: _Fields = {
    "latent_dim": ("an integer", _is_integer),
    "mean": ("a number", _is_number),
    "standard_error": ("a number", _is_number),
    "difference": ("a number", _is_number),
    "difference_standard_error": ("a number", _is_number),
    "fold_scores": (f"a list of at most {MAX_RECORD_ITEMS} numbers", _list_of(_is_number)),
}


def _check_object(
    value: Any, where: str, fields: _Fields, required: bool = False
) -> Mapping[str, Any]:
    """``value`` is an object whose ``fields`` are of their kind (and all present, when
    ``required``); other fields are left alone."""
    if not isinstance(value, Mapping):
        raise DocumentError(f"model document: {where} must be an object.", column=where)
    for name, (kind, check) in fields.items():
        if name not in value:
            if required:
                raise DocumentError(
                    f"model document: {where} has no field {name!r}.", column=f"{where}.{name}"
                )
        elif not check(value[name]):
            raise DocumentError(
                f"model document: {where}.{name} must be {kind}.", column=f"{where}.{name}"
            )
    return value


def _objects(value: Any, where: str) -> list[Mapping[str, Any]]:
    """A list of objects (``objects``, ``hyperparameters``)."""
    if not isinstance(value, list):
        raise DocumentError(f"model document: {where} must be a list.", column=where)
    for i, item in enumerate(value):
        if not isinstance(item, Mapping):
            raise DocumentError(
                f"model document: {where}[{i}] must be an object.", column=f"{where}[{i}]"
            )
    return value


def _array(where: str, values: Any) -> npt.NDArray[np.float64]:
    """``values`` as a float array, or an error naming the field ``where``."""
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DocumentError(
            f"model document: {where} must be numbers in arrays of matching lengths "
            f"({type(exc).__name__}: {reprlib.repr(str(exc))}).",
            column=where,
        ) from exc


def _field(document: Mapping[str, Any], name: str, where: str = "model document") -> Any:
    if name not in document:
        raise DocumentError(f"{where}: missing field {name!r}.", column=name)
    return document[name]


class _Calibration(NamedTuple):
    """One optional calibration value of a model document: ``document[field][key]``."""

    field: str
    key: str
    #: The :class:`ManifoldModel` attribute it sets.
    attribute: str
    #: The check of its value against the model read so far.
    check: Callable[[ManifoldModel, Any], Any]
    #: Whether ``key`` may be absent when ``field`` is present (added after the field was).
    key_optional: bool = False


#: The optional calibration fields of a model document, in the order they are read.
_CALIBRATIONS: tuple[_Calibration, ...] = (
    _Calibration(
        "latent_uncertainty",
        "covariance",
        "latent_covariance",
        lambda model, value: check_latent_covariance(model, np.asarray(value, dtype=np.float64)),
    ),
    _Calibration("tempering", "exponent", "tempering", lambda _model, value: check_exponent(value)),
    _Calibration(
        "placement_effect",
        "variance",
        "placement_variance",
        lambda model, value: check_placement_variance(model, np.asarray(value, dtype=np.float64)),
    ),
    # After the placement effect: σ_b² + σ_d² must stay below σ_n².
    _Calibration("drift_effect", "variance", "drift_variance", check_drift_variance),
    # After the drift (σ_b,l² + σ_d² below σ_n²); documents written before it have none.
    _Calibration(
        "placement_effect",
        "by_object",
        "object_placement_variance",
        check_object_placement_variance,
        key_optional=True,
    ),
    _Calibration("input_shift", "variance", "shift_variance", check_shift_variance),
    # Documents written before the creep have none.
    _Calibration(
        "input_shift", "creep", "shift_creep_variance", check_shift_creep, key_optional=True
    ),
)


def _read_calibration(
    document: Mapping[str, Any], entry: _Calibration, check: Callable[[Any], _T]
) -> _T | None:
    """The optional value ``entry`` of a model document, through ``check``.

    Returns:
        What ``check`` makes of the value at ``entry.key``; ``None`` when the field is absent
        (or the key, if it may be).

    Raises:
        DocumentError: (column ``name``) ``key`` is missing, ``check`` refused the value
            (its message), or the value is malformed.
    """
    name, key = entry.field, entry.key
    field = document.get(name)
    if field is None:
        return None
    if entry.key_optional and isinstance(field, Mapping) and key not in field:
        return None
    try:
        return check(_field(field, key, name))
    except InvalidInputError as exc:
        raise DocumentError(f"model document: {exc}", column=name) from exc
    except (TypeError, ValueError) as exc:
        raise DocumentError(
            f"model document: malformed field {name!r} ({exc}).", column=name
        ) from exc


def model_from_document(document: Any) -> ManifoldModel:
    """Rebuild a :class:`ManifoldModel` from its document (re-conditioning the GP).

    Raises:
        DocumentError: Wrong format tag, missing fields, values that are not finite numbers,
            names or text too long, or inconsistent dimensions (the message names the field).
    """
    if not isinstance(document, Mapping):
        raise DocumentError("model document: expected a JSON object.")
    check_json_values(
        document, "model document", max_depth=MAX_DOCUMENT_DEPTH, max_text=MAX_TEXT_CHARACTERS
    )
    if _field(document, "format") != MODEL_FORMAT:
        raise DocumentError(
            f"model document: format must be {MODEL_FORMAT!r}, found "
            f"{reprlib.repr(document['format'])}.",
            column="format",
        )
    _check_number(document, "log_likelihood")
    _check_number(document, "fit_seconds", minimum=0.0)
    if "name" in document:
        _name(document["name"], "name")
    objects = _objects(_field(document, "objects"), "objects")
    hyper = _objects(_field(document, "hyperparameters"), "hyperparameters")
    training = _check_object(_field(document, "training_data"), "training_data", {})
    names = [
        _name(_field(o, "name", f"objects[{i}]"), f"objects[{i}].name")
        for i, o in enumerate(objects)
    ]
    touch_objects = _names(_field(training, "objects", "training_data"), "training_data.objects")
    unknown = sorted(set(touch_objects) - set(names))
    if unknown:
        raise DocumentError(
            f"training_data.objects: names {reprlib.repr(unknown)} are not in 'objects'.",
            column="training_data.objects",
        )
    try:
        data = TrainingData(
            object_names=tuple(names),
            object_index=np.asarray([names.index(n) for n in touch_objects], dtype=np.int64),
            actions=_array("training_data.actions", _field(training, "actions", "training_data")),
            observations=_array(
                "training_data.observations", _field(training, "observations", "training_data")
            ),
            placement_index=(
                None
                if training.get("placements") is None
                else np.asarray(training["placements"], dtype=np.int64)
            ),
            touch_times_s=(
                None
                if training.get("times_s") is None
                else _array("training_data.times_s", training["times_s"])
            ),
            touch_duration_s=_duration_s(training.get("duration_s")),
        )
        per_feature = {
            name: [_field(f, name, f"hyperparameters[{a}]") for a, f in enumerate(hyper)]
            for name in (
                "signal_variance",
                "noise_variance",
                "latent_lengthscales",
                "action_lengthscales",
            )
        }
        hyperparameters = Hyperparameters(
            **{
                name: _array(f"hyperparameters[].{name}", values)
                for name, values in per_feature.items()
            }
        )
        latents = _array(
            "objects[].latent",
            [_field(o, "latent", f"objects[{i}]") for i, o in enumerate(objects)],
        )
    except DocumentError:
        raise
    except InvalidInputError as exc:
        raise DocumentError(f"model document: {exc}") from exc
    for name, expected, actual in (
        ("latent_dim", hyperparameters.latent_dim, document.get("latent_dim")),
        ("action_dim", data.action_dim, document.get("action_dim")),
        ("observation_dim", data.observation_dim, document.get("observation_dim")),
    ):
        if actual is not None and actual != expected:
            raise DocumentError(
                f"model document: {name} is {reprlib.repr(actual)} but the arrays say {expected}.",
                column=name,
            )
    diagnostics = None
    if document.get("diagnostics") is not None:
        d = _check_object(document["diagnostics"], "diagnostics", _DIAGNOSTICS_FIELDS)
        diagnostics = FitDiagnostics(
            starts_log_likelihood=tuple(float(v) for v in d.get("starts_log_likelihood", [])),
            best_start=int(d.get("best_start", 0)),
            iterations=int(d.get("iterations", 0)),
            converged=bool(d.get("converged", False)),
            message=str(d.get("message", "")),
            jitter_used=float(d.get("jitter_used", 0.0)),
            hyperparameters_at_bounds=tuple(d.get("hyperparameters_at_bounds", [])),
            kernels=str(d.get("kernels", "per_feature")),
        )
    if document.get("latent_selection") is not None:
        selection = _check_object(
            document["latent_selection"], "latent_selection", _LATENT_SELECTION_FIELDS, True
        )
        for i, candidate in enumerate(selection["candidates"]):
            _check_object(candidate, f"latent_selection.candidates[{i}]", _CANDIDATE_FIELDS, True)
    transform = read_noise_model_field(document.get("noise_model"), data.observation_dim)
    features = read_features_field(document.get("features"), data.observation_dim)
    model = condition_as_recorded(
        data,
        latents,
        hyperparameters,
        diagnostics,
        document.get("posterior"),
        transform=transform,
        placement_variance=placement_in_fit_variance(document),
    )
    if features is not None:
        model = dataclasses.replace(model, features=features)
    return read_calibrations(document, model)
