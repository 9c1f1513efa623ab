"""The ``posterior`` field: how a model's GP was conditioned, so a reloaded model predicts exactly
as the original.

``{"structure": "dense"}``, ``{"structure": "kronecker"}`` or ``{"structure": "sparse",
"n_inducing": m, "inducing_touches": [...]}`` (the training touches used as inducing points, in
order). Documents written before the field existed still load: their posterior is chosen as
:func:`core.gp.posterior.condition` does by default (``structure="auto"``). The same field is stored
on a model row: :func:`posterior_field` writes it, :func:`read_posterior_field` parses it and
:func:`condition_as_recorded` rebuilds the GP.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from app.documents.errors import DocumentError, read_kind
from core.errors import InvalidInputError
from core.gp import Structure, attach_transform, condition, condition_sparse, transform_data
from core.observation_transform import ObservationTransform
from core.types import (
    FitDiagnostics,
    GPPosterior,
    Hyperparameters,
    InducingPoints,
    ManifoldModel,
    TrainingData,
)


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


_STRUCTURES = ("dense", "kronecker", "sparse")


@dataclass(frozen=True)
class RecordedPosterior:
    """A parsed ``posterior`` field (:func:`read_posterior_field`).

    Attributes:
        structure: ``"dense"``, ``"kronecker"`` or ``"sparse"``.
        n_inducing: m for a sparse posterior (1 otherwise, unused).
        inducing: The recorded inducing points of a sparse posterior (training touches), or
            ``None``: dense, Kronecker, or sparse with only ``n_inducing`` recorded (the points
            are then selected as :func:`core.gp.posterior.condition` does).
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
    field, structure = read_kind(field, "posterior", "structure", _STRUCTURES, where)
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
    placement_variance: npt.NDArray[np.float64] | None = None,
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
            as :func:`core.gp.posterior.condition` chooses by default (``structure="auto"``).
        where: What holds the field, to start error messages (``"model document"``).
        transform: The observation transform the model was fitted with (``None``: identity);
            the GP is conditioned on the transformed observations and keeps the transform.
        placement_variance: σ_b² in the training covariance (a model fitted with its
            placement effect, :func:`core.gp.posterior.condition`); ``None``: none.

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
        if placement_variance is not None:
            model = condition(
                model_data,
                latents,
                hyperparameters,
                diagnostics,
                structure="dense" if recorded is None else recorded.structure,
                placement_variance=placement_variance,
            )
        elif recorded is None:
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
