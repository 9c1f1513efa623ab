"""File formats: the training CSV and the model document ("activetouch-model/1").

CSV (DESIGN.md): header ``object,x_1,...,x_dx,y_1,...,y_dy``, one touch per row.
Model document: a self-contained JSON object from which the model can be reloaded and used to
predict, plan and recognise (the training data is included; β and K⁻¹ are recomputed).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from core.errors import InvalidInputError
from core.posterior import condition
from core.types import FitDiagnostics, Hyperparameters, ManifoldModel, TrainingData

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


def write_training_csv(data: TrainingData) -> str:
    """Render training data as CSV text (floats written with ``repr``, so they round-trip)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(
        ["object"]
        + [f"x_{i + 1}" for i in range(data.action_dim)]
        + [f"y_{i + 1}" for i in range(data.observation_dim)]
    )
    for obj, x, y in zip(data.object_index, data.actions, data.observations, strict=True):
        writer.writerow(
            [data.object_names[obj], *map(repr, map(float, x)), *map(repr, map(float, y))]
        )
    return out.getvalue()


def model_to_document(model: ManifoldModel, fit_seconds: float | None = None) -> dict[str, Any]:
    """The model document (format ``activetouch-model/1``) as a JSON-ready dict."""
    h = model.hyperparameters
    data = model.data
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
        "training_data": {
            "objects": [data.object_names[i] for i in data.object_index],
            "actions": data.actions.tolist(),
            "observations": data.observations.tolist(),
        },
    }
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
    try:
        return condition(data, latents, hyperparameters, diagnostics)
    except InvalidInputError as exc:
        raise DocumentError(f"model document: {exc}") from exc
