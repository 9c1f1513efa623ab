"""File formats: the training CSV and the model document ("activetouch-model/1").

CSV (DESIGN.md): header ``object,x_1,...,x_dx,y_1,...,y_dy``, one touch per row.
:class:`TrainingCsvWriter` appends rows as touches arrive (a collection keeps what it recorded).

Model document: a self-contained JSON object from which the model can be reloaded and used to
predict, plan and recognise (the training data is included; β and K⁻¹ are recomputed). Its
``posterior`` field records how the GP was conditioned: ``{"structure": "dense"}``,
``{"structure": "kronecker"}`` or ``{"structure": "sparse", "n_inducing": m,
"inducing_touches": [...]}`` (the training touches used as inducing points, in order), so the
reloaded model predicts exactly as the original. Documents written before that field existed
still load: their posterior is chosen as :func:`core.posterior.condition` does by default
(``structure="auto"``). The same field is stored on a model row: :func:`posterior_field` writes
it, :func:`read_posterior_field` parses it and :func:`condition_as_recorded` rebuilds the GP.

The ``noise_model`` field records the observation transform y' = W ((y - offset) / scale) the GPs
were fitted in (:mod:`core.observation_transform`, docs/noise-model.md): ``{"kind":
"independent" | "correlated", "offset": [...], "scale": [...], "whitening": [[...]],
"correlation": [[...]], "note": "..."}``. The training data stay in raw units. A document
without the field (written before it existed) loads with the identity transform, as it was
fitted. On a model row the same dict is kept inside the ``posterior`` record (key
``noise_model``). ``latent_selection`` (optional) reports how ``--latent-dim auto`` chose ds.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

import numpy as np
import numpy.typing as npt

from core.errors import InvalidInputError
from core.latent_selection import LatentSelection
from core.noise_model import attach_transform, transform_data
from core.observation_transform import TRANSFORM_KINDS, ObservationTransform
from core.posterior import Structure, condition
from core.sparse import condition_sparse
from core.types import (
    FitDiagnostics,
    GPPosterior,
    Hyperparameters,
    InducingPoints,
    ManifoldModel,
    TrainingData,
)

MODEL_FORMAT = "activetouch-model/1"
_ACTION_COLUMN = re.compile(r"^x_(\d+)$")
_OBSERVATION_COLUMN = re.compile(r"^y_(\d+)$")


class DocumentError(InvalidInputError):
    """A CSV or model document is malformed; says where (row, column, field) and why.

    Attributes:
        row: 1-based line number in the file (the header is line 1), if the problem is in a row.
        column: Column or field name, if known.
    """

    def __init__(self, message: str, row: int | None = None, column: str | None = None) -> None:
        super().__init__(message)
        self.row = row
        self.column = column


def _check_header(header: list[str]) -> tuple[int, int]:
    """Validate the CSV header; return (dx, dy)."""
    names = [h.strip() for h in header]
    if not names or names[0] != "object":
        raise DocumentError(
            f"CSV header: the first column must be 'object', found {names[:1] or 'nothing'}.",
            row=1,
            column=names[0] if names else None,
        )
    unknown = [
        n for n in names[1:] if not (_ACTION_COLUMN.match(n) or _OBSERVATION_COLUMN.match(n))
    ]
    if unknown:
        raise DocumentError(
            f"CSV header: unknown column(s) {unknown}; expected object,x_1..x_dx,y_1..y_dy.",
            row=1,
            column=unknown[0],
        )
    actions = [n for n in names[1:] if _ACTION_COLUMN.match(n)]
    observations = [n for n in names[1:] if _OBSERVATION_COLUMN.match(n)]
    expected = (
        ["object"]
        + [f"x_{i + 1}" for i in range(len(actions))]
        + [f"y_{i + 1}" for i in range(len(observations))]
    )
    if not actions or not observations or names != expected:
        wanted = (
            ",".join(expected)
            if actions and observations
            else "object,x_1..x_dx,y_1..y_dy with at least one x and one y"
        )
        raise DocumentError(f"CSV header: expected {wanted}, found {','.join(names)}.", row=1)
    return len(actions), len(observations)


def read_training_csv(text: str) -> TrainingData:
    """Parse and validate a training CSV.

    Raises:
        DocumentError: Unknown or misordered columns, ragged rows, values that are not finite
            numbers (the message names row and column), or too few objects / touches.
    """
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader)
    except StopIteration:
        raise DocumentError("CSV: the file is empty; expected a header line.", row=1) from None
    dx, dy = _check_header(header)
    columns = [h.strip() for h in header]
    names: list[str] = []
    index: list[int] = []
    values: list[list[float]] = []
    for line_number, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(columns):
            raise DocumentError(
                f"CSV row {line_number}: has {len(row)} fields, the header has {len(columns)}.",
                row=line_number,
            )
        name = row[0].strip()
        if not name:
            raise DocumentError(
                f"CSV row {line_number}: the object name is empty.",
                row=line_number,
                column="object",
            )
        numbers = []
        for column, cell in zip(columns[1:], row[1:], strict=True):
            try:
                number = float(cell)
            except ValueError:
                raise DocumentError(
                    f"CSV row {line_number}, column {column}: {cell!r} is not a number.",
                    row=line_number,
                    column=column,
                ) from None
            if not math.isfinite(number):
                raise DocumentError(
                    f"CSV row {line_number}, column {column}: {cell!r} is not finite.",
                    row=line_number,
                    column=column,
                )
            numbers.append(number)
        if name not in names:
            names.append(name)
        index.append(names.index(name))
        values.append(numbers)
    if not values:
        raise DocumentError("CSV: no data rows after the header.", row=2)
    array = np.asarray(values, dtype=np.float64)
    try:
        return TrainingData(
            object_names=tuple(names),
            object_index=np.asarray(index, dtype=np.int64),
            actions=array[:, :dx],
            observations=array[:, dx : dx + dy],
        )
    except DocumentError:
        raise
    except InvalidInputError as exc:
        raise DocumentError(f"CSV: {exc}") from exc


def training_csv_header(action_dim: int, observation_dim: int) -> list[str]:
    """The CSV header ``object,x_1..x_dx,y_1..y_dy``."""
    return (
        ["object"]
        + [f"x_{i + 1}" for i in range(action_dim)]
        + [f"y_{i + 1}" for i in range(observation_dim)]
    )


class TrainingCsvWriter:
    """Write a training CSV touch by touch: the header at once, then one row per :meth:`write`.

    Floats are written with ``repr``, so they round-trip exactly. Rows are not validated as a
    whole (a partial collection may have an object with one touch); :func:`read_training_csv`
    checks the file when it is used.

    Args:
        stream: Text stream to write to (opened with ``newline=""`` for a file).
        action_dim: dx.
        observation_dim: dy.
    """

    def __init__(self, stream: TextIO, action_dim: int, observation_dim: int) -> None:
        if action_dim < 1 or observation_dim < 1:
            raise DocumentError(
                f"CSV: needs dx ≥ 1 and dy ≥ 1, received dx={action_dim}, dy={observation_dim}."
            )
        self.action_dim = int(action_dim)
        self.observation_dim = int(observation_dim)
        self.rows = 0
        self._writer = csv.writer(stream, lineterminator="\n")
        self._writer.writerow(training_csv_header(self.action_dim, self.observation_dim))

    def write(self, name: str, action: npt.ArrayLike, observation: npt.ArrayLike) -> None:
        """Append one touch: object ``name``, action (dx,), observation (dy,).

        Raises:
            DocumentError: An empty name, wrong lengths or values that are not finite.
        """
        x = np.asarray(action, dtype=np.float64).reshape(-1)
        y = np.asarray(observation, dtype=np.float64).reshape(-1)
        if not name.strip():
            raise DocumentError("CSV: the object name is empty.", column="object")
        for what, values, expected in (
            ("action", x, self.action_dim),
            ("observation", y, self.observation_dim),
        ):
            if values.shape[0] != expected:
                raise DocumentError(
                    f"CSV: {what} of {name!r} has {values.shape[0]} values, expected {expected}."
                )
            if not np.all(np.isfinite(values)):
                raise DocumentError(f"CSV: {what} of {name!r} is not finite: {values.tolist()}.")
        self._writer.writerow([name, *map(repr, map(float, x)), *map(repr, map(float, y))])
        self.rows += 1


def write_training_csv(data: TrainingData) -> str:
    """Render training data as CSV text (floats written with ``repr``, so they round-trip)."""
    out = io.StringIO()
    writer = TrainingCsvWriter(out, data.action_dim, data.observation_dim)
    for obj, x, y in zip(data.object_index, data.actions, data.observations, strict=True):
        writer.write(data.object_names[obj], x, y)
    return out.getvalue()


def posterior_field(posterior: GPPosterior) -> dict[str, Any]:
    """How the GP was conditioned, as the model document's ``posterior`` field records it.

    The same JSON-ready dict is stored on a model row (``models.posterior``) and read back by
    :func:`read_posterior_field` / :func:`condition_as_recorded`.

    Args:
        posterior: A conditioned GP (``model.posterior``).

    Returns:
        ``{"structure": "dense"}``, ``{"structure": "kronecker"}`` or ``{"structure": "sparse",
        "n_inducing": m, "inducing_touches": [...]}`` (the training touches used as inducing
        points, in order: indices into the training data's touches, 0..N-1).
    """
    field: dict[str, Any] = {"structure": str(posterior.structure)}
    if posterior.inducing is not None:
        field["n_inducing"] = posterior.inducing.size
        field["inducing_touches"] = [int(i) for i in posterior.inducing.touch_index]
    return field


def noise_model_field(transform: ObservationTransform | None) -> dict[str, Any] | None:
    """The model document's ``noise_model`` field (``None`` for no transform)."""
    if transform is None or transform.kind == "identity":
        return None
    return {
        "kind": transform.kind,
        "offset": [float(v) for v in transform.offset],
        "scale": [float(v) for v in transform.scale],
        "whitening": transform.whitening.tolist(),
        "correlation": transform.correlation.tolist(),
        "note": transform.note,
    }


def read_noise_model_field(
    field: Any, observation_dim: int, where: str = "model document"
) -> ObservationTransform | None:
    """Parse a ``noise_model`` field (:func:`noise_model_field`); ``None`` when absent.

    Raises:
        DocumentError: Not an object, an unknown kind, or arrays of the wrong shape or not
            finite / not invertible (``column`` names ``noise_model.<field>``).
    """
    if field is None:
        return None
    if not isinstance(field, Mapping):
        raise DocumentError(
            f"{where}: 'noise_model' must be an object, found {type(field).__name__}.",
            column="noise_model",
        )
    kind = field.get("kind")
    if kind not in TRANSFORM_KINDS:
        raise DocumentError(
            f"{where}: noise_model.kind must be one of {', '.join(TRANSFORM_KINDS)}, found "
            f"{kind!r}.",
            column="noise_model.kind",
        )
    if kind == "identity":
        return None
    arrays = {}
    for name, shape in (
        ("offset", (observation_dim,)),
        ("scale", (observation_dim,)),
        ("whitening", (observation_dim, observation_dim)),
        ("correlation", (observation_dim, observation_dim)),
    ):
        try:
            value = np.asarray(field.get(name), dtype=np.float64)
        except (TypeError, ValueError):
            value = np.zeros(0)
        if value.shape != shape or not np.all(np.isfinite(value)):
            raise DocumentError(
                f"{where}: noise_model.{name} must be a finite array of shape {shape} "
                f"(dy = {observation_dim}).",
                column=f"noise_model.{name}",
            )
        arrays[name] = value
    try:
        return ObservationTransform(
            kind,
            arrays["offset"],
            arrays["scale"],
            arrays["whitening"],
            arrays["correlation"],
            str(field.get("note", "")),
        )
    except InvalidInputError as exc:
        raise DocumentError(f"{where}: noise_model: {exc}", column="noise_model") from exc


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
    return condition_as_recorded(
        data, latents, hyperparameters, diagnostics, document.get("posterior"), transform=transform
    )


_STRUCTURES = ("dense", "kronecker", "sparse")


@dataclass(frozen=True)
class RecordedPosterior:
    """A parsed ``posterior`` field (:func:`read_posterior_field`).

    Attributes:
        structure: ``"dense"``, ``"kronecker"`` or ``"sparse"``.
        n_inducing: m for a sparse posterior (1 otherwise, unused).
        inducing: The recorded inducing points of a sparse posterior (training touches), or
            ``None``: dense, Kronecker, or sparse with only ``n_inducing`` recorded (the points
            are then selected as :func:`core.posterior.condition` does).
    """

    structure: Structure
    n_inducing: int
    inducing: InducingPoints | None


def read_posterior_field(
    field: Any, data: TrainingData, where: str = "model document"
) -> RecordedPosterior | None:
    """Parse and check a ``posterior`` field (as :func:`posterior_field` writes it).

    Args:
        field: The field's JSON value: a dict, or ``None`` when it is absent (a document or a
            model row written before it existed).
        data: The training data the posterior was conditioned on (N touches), which the
            inducing touches index.
        where: What holds the field, to start error messages (``"model document"``).

    Returns:
        The structure and, for a sparse posterior, m and the inducing points; ``None`` when
        ``field`` is ``None``.

    Raises:
        DocumentError: ``field`` is not an object; the structure is not dense, kronecker or
            sparse; a sparse field has neither ``inducing_touches`` nor an integer
            ``n_inducing`` ≥ 1; ``inducing_touches`` is not a non-empty list of distinct integer
            indices in 0..N-1; or ``n_inducing`` disagrees with it. ``column`` names the
            field (``posterior.structure``, ``posterior.n_inducing``,
            ``posterior.inducing_touches``).
    """
    if field is None:
        return None
    if not isinstance(field, Mapping):
        raise DocumentError(
            f"{where}: 'posterior' must be an object, found {type(field).__name__}.",
            column="posterior",
        )
    structure = field.get("structure")
    if structure not in _STRUCTURES:
        raise DocumentError(
            f"{where}: posterior.structure must be one of {', '.join(_STRUCTURES)}, "
            f"found {structure!r}.",
            column="posterior.structure",
        )
    if structure == "dense" or structure == "kronecker":
        return RecordedPosterior(structure, 1, None)
    n_inducing: Any = field.get("n_inducing")
    touches = field.get("inducing_touches")
    if touches is None:
        if not _is_count(n_inducing):
            raise DocumentError(
                f"{where}: a sparse posterior needs 'inducing_touches' or an integer "
                f"'n_inducing' ≥ 1, found n_inducing={n_inducing!r}.",
                column="posterior.n_inducing",
            )
        return RecordedPosterior("sparse", int(n_inducing), None)
    index = _touch_indices(touches, data.n_touches, where)
    if n_inducing is not None and n_inducing != index.shape[0]:
        raise DocumentError(
            f"{where}: posterior.n_inducing is {n_inducing!r} but "
            f"'inducing_touches' lists {index.shape[0]} touches.",
            column="posterior.n_inducing",
        )
    index.flags.writeable = False
    inducing = InducingPoints(
        object_index=data.object_index[index], actions=data.actions[index], touch_index=index
    )
    return RecordedPosterior("sparse", int(index.shape[0]), inducing)


def condition_as_recorded(
    data: TrainingData,
    latents: npt.NDArray[np.float64],
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None,
    field: Any,
    where: str = "model document",
    transform: ObservationTransform | None = None,
) -> ManifoldModel:
    """Condition the GP exactly as a ``posterior`` field recorded (:func:`posterior_field`).

    Deterministic: the same inputs give the same posterior, so a reloaded model predicts as the
    original did.

    Args:
        data: The training touches (N of them, in the order the field's indices refer to).
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.
        diagnostics: Fit diagnostics to attach, if any.
        field: The ``posterior`` field; ``None`` (written before the field existed) conditions
            as :func:`core.posterior.condition` chooses by default (``structure="auto"``).
        where: What holds the field, to start error messages (``"model document"``).
        transform: The observation transform the model was fitted with (``None``: identity);
            the GP is conditioned on the transformed observations and keeps the transform.

    Returns:
        The conditioned model.

    Raises:
        DocumentError: The field is malformed (see :func:`read_posterior_field`), or the
            recorded structure cannot be used for the data (e.g. Kronecker without a shared
            design) or with these latents/hyperparameters (any
            :class:`core.errors.InvalidInputError`, prefixed by ``where``).
        core.errors.CoreError: The conditioning itself fails (e.g. a matrix that stays non
            positive definite).
    """
    recorded = read_posterior_field(field, data, where)
    try:
        model_data = data if transform is None else transform_data(data, transform)
        if recorded is None:
            model = condition(model_data, latents, hyperparameters, diagnostics)
        elif recorded.inducing is not None:
            model = condition_sparse(
                model_data, latents, hyperparameters, diagnostics, inducing=recorded.inducing
            )
        else:
            model = condition(
                model_data,
                latents,
                hyperparameters,
                diagnostics,
                structure=recorded.structure,
                n_inducing=recorded.n_inducing,
            )
        return model if transform is None else attach_transform(model, transform, data)
    except DocumentError:
        raise
    except InvalidInputError as exc:
        raise DocumentError(f"{where}: {exc}") from exc


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def _touch_indices(values: Any, n_touches: int, where: str) -> npt.NDArray[np.int64]:
    """Validate ``posterior.inducing_touches``: distinct touch indices in [0, N)."""
    column = "posterior.inducing_touches"
    if (
        not isinstance(values, Sequence)
        or isinstance(values, str)
        or not values
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in values)
    ):
        raise DocumentError(
            f"{where}: {column} must be a non-empty list of touch indices (distinct integers).",
            column=column,
        )
    index = np.asarray(values, dtype=np.int64)
    outside = index[(index < 0) | (index >= n_touches)]
    if outside.size:
        raise DocumentError(
            f"{where}: {column} has {outside[:3].tolist()} outside 0..{n_touches - 1} "
            "(the training touches).",
            column=column,
        )
    if np.unique(index).shape[0] != index.shape[0]:
        raise DocumentError(
            f"{where}: {column} repeats a touch (they must be distinct).", column=column
        )
    return index
