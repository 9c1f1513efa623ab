"""The ``noise_model`` field: the observation transform y' = W ((y - offset) / scale) the GPs were
fitted in (:mod:`core.observation_transform`, docs/noise-model.md).

``{"kind": "independent" | "correlated", "offset": [...], "scale": [...], "whitening": [[...]],
"correlation": [[...]], "note": "..."}``. The training data stay in raw units. A document without
the field (written before it existed) loads with the identity transform, as it was fitted. On a
model row the same dict is kept inside the ``posterior`` record (key ``noise_model``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.documents.errors import DocumentError, read_kind
from core.errors import InvalidInputError
from core.observation_transform import TRANSFORM_KINDS, ObservationTransform


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
    field, kind = read_kind(field, "noise_model", "kind", TRANSFORM_KINDS, where)
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
