"""Choose the latent dimension ds by cross-validated held-out predictive likelihood.

The touches of every object are split across K folds (each object keeps touches in every
training set, so its latent can be learned); for each candidate ds and fold, a model is fitted
on the other folds and scored by the mean log-density of the held-out touches under their own
object's learned latent (:func:`core.object_posterior.touch_log_likelihoods`, raw units,
Jacobian included). The choice is the candidate with the best mean score over folds (exact ties
go to the smaller ds). Every candidate also reports its paired difference to the best (fold by
fold, which cancels the fold-to-fold variation common to all candidates) with its standard
error, and the explanation names smaller ds within one standard error of the choice (where the
one-standard-error rule of Hastie, Tibshirani & Friedman, §7.10, would have stopped). That rule
was tried as the choice and measured worse on Experiment-2-like worlds (docs/noise-model.md):
it leaned to too small a ds.

Pure maths: the fit is a function argument, randomness comes in as a generator.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.object_posterior import touch_log_likelihoods
from core.types import ManifoldModel, TrainingData
from core.validation import IntArray

#: Largest candidate ds tried by default (candidates 1..min(this, L - 1)).
DEFAULT_MAX_LATENT_DIM = 5
DEFAULT_FOLDS = 5


@dataclass(frozen=True)
class CandidateScore:
    """Cross-validated score of one latent dimension.

    Attributes:
        latent_dim: ds.
        fold_scores: Mean held-out log-density per touch (nats) of each fold.
        mean: Mean of ``fold_scores``.
        standard_error: Standard error of ``mean`` over the folds.
        difference: Mean over folds of this candidate's score minus the best candidate's.
        difference_standard_error: Standard error of ``difference`` (0 for the best).
    """

    latent_dim: int
    fold_scores: tuple[float, ...]
    mean: float
    standard_error: float
    difference: float
    difference_standard_error: float


@dataclass(frozen=True)
class LatentSelection:
    """The outcome of :func:`select_latent_dim`.

    Attributes:
        chosen: The chosen ds.
        best: The ds with the best mean held-out score (= ``chosen`` up to ties).
        n_folds: K.
        candidates: Every candidate's scores, in increasing ds.
        explanation: One sentence saying why ``chosen`` was chosen.
    """

    chosen: int
    best: int
    n_folds: int
    candidates: tuple[CandidateScore, ...]
    explanation: str


def candidate_dims(n_objects: int, max_latent_dim: int = DEFAULT_MAX_LATENT_DIM) -> tuple[int, ...]:
    """1..min(max_latent_dim, L - 1): L objects are placed exactly by L - 1 dimensions."""
    top = min(int(max_latent_dim), int(n_objects) - 1)
    if top < 1:
        raise InvalidInputError(
            f"latent dimension candidates: need L ≥ 2 objects and max_latent_dim ≥ 1, received "
            f"L={n_objects}, max_latent_dim={max_latent_dim}."
        )
    return tuple(range(1, top + 1))


def fold_assignment(object_index: IntArray, n_folds: int, rng: np.random.Generator) -> IntArray:
    """Fold of every touch: each object's touches shuffled and dealt round-robin to K folds.

    Args:
        object_index: Object of every touch. Shape (N,).
        n_folds: K ≥ 2.
        rng: Random generator (the shuffle).

    Returns:
        Fold of every touch, 0..K-1. Shape (N,).

    Raises:
        InvalidInputError: K < 2, or an object with fewer than K + 2 touches (every fold's
            training set needs at least 2 touches of every object and every fold one held-out
            touch of it).
    """
    index = np.asarray(object_index, dtype=np.int64)
    if int(n_folds) < 2:
        raise InvalidInputError(f"n_folds: need at least 2, received {n_folds}.")
    folds = np.empty(index.shape[0], dtype=np.int64)
    for obj in np.unique(index):
        touches = np.flatnonzero(index == obj)
        if touches.shape[0] < n_folds + 2:
            raise InvalidInputError(
                f"cross-validation with {n_folds} folds: object {int(obj)} has "
                f"{touches.shape[0]} touches, at least {n_folds + 2} are needed."
            )
        folds[rng.permutation(touches)] = np.arange(touches.shape[0]) % n_folds
    return folds


def _subset(data: TrainingData, keep: IntArray) -> TrainingData:
    return TrainingData(
        object_names=data.object_names,
        object_index=data.object_index[keep],
        actions=data.actions[keep],
        observations=data.observations[keep],
    )


def select_latent_dim(
    data: TrainingData,
    fit: Callable[[TrainingData, int], ManifoldModel],
    rng: np.random.Generator,
    candidates: Sequence[int] | None = None,
    n_folds: int = DEFAULT_FOLDS,
    callback: Callable[[int, int, float], None] | None = None,
) -> LatentSelection:
    """Choose ds by K-fold cross-validation over touches within objects (module docstring).

    Args:
        data: Raw training touches.
        fit: Fits a model to training touches at a latent dimension (raw data in, a model that
            maps raw observations itself out, e.g. with a noise model).
        rng: Random generator (the fold assignment).
        candidates: The ds to try; default :func:`candidate_dims`.
        n_folds: K ≥ 2.
        callback: Called after every fold fit with (ds, fold, score).

    Returns:
        The scores and the choice.

    Raises:
        InvalidInputError: Bad candidates or folds (too few touches per object).
    """
    dims = tuple(candidates) if candidates is not None else candidate_dims(data.n_objects)
    if not dims or any(int(d) != d or d < 1 for d in dims) or len(set(dims)) != len(dims):
        raise InvalidInputError(
            f"candidates: expected distinct integers ≥ 1, received {list(dims)}."
        )
    dims = tuple(sorted(int(d) for d in dims))
    folds = fold_assignment(data.object_index, n_folds, rng)
    scores = np.empty((len(dims), n_folds))
    for k in range(n_folds):
        held = np.flatnonzero(folds == k)
        train = _subset(data, np.flatnonzero(folds != k))
        for c, ds in enumerate(dims):
            model = fit(train, ds)
            values = touch_log_likelihoods(
                model, data.object_index[held], data.actions[held], data.observations[held]
            )
            scores[c, k] = float(values.mean())
            if callback is not None:
                callback(ds, k, scores[c, k])
    means = scores.mean(axis=1)
    best_row = int(np.argmax(means))
    root_k = np.sqrt(n_folds)
    results = []
    for c, ds in enumerate(dims):
        difference = scores[c] - scores[best_row]
        results.append(
            CandidateScore(
                latent_dim=ds,
                fold_scores=tuple(float(v) for v in scores[c]),
                mean=float(means[c]),
                standard_error=float(scores[c].std(ddof=1) / root_k),
                difference=float(difference.mean()),
                difference_standard_error=float(difference.std(ddof=1) / root_k),
            )
        )
    # The best mean wins; exact ties (within round-off) go to the smaller ds.
    tolerance = 1e-9 * (1.0 + abs(float(means.max())))
    chosen = next(r for r in results if r.mean >= float(means.max()) - tolerance)
    close = [
        r.latent_dim
        for r in results
        if r.latent_dim < chosen.latent_dim and r.difference >= -r.difference_standard_error
    ]
    explanation = (
        f"ds = {chosen.latent_dim}: the best mean held-out log-likelihood "
        f"({chosen.mean:.3f} ± {chosen.standard_error:.3f} nats per touch over {n_folds} folds)"
    )
    if close:
        explanation += (
            f"; ds = {', '.join(map(str, close))} within one standard error of it (paired over "
            f"folds), so the data only weakly prefer the larger latent space."
        )
    elif chosen.latent_dim > dims[0]:
        explanation += "; every smaller ds is worse by more than one standard error."
    else:
        explanation += "; every larger ds predicts held-out touches worse."
    return LatentSelection(
        chosen=chosen.latent_dim,
        best=results[best_row].latent_dim,
        n_folds=int(n_folds),
        candidates=tuple(results),
        explanation=explanation,
    )
