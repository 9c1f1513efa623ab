"""Leave-objects-out scoring of a latent dimension (``criterion="objects"`` of
:func:`core.selection.latent_selection.select_latent_dim`).

The objects are dealt to folds; a model fitted without a fold's objects meets each of them as
a new object: its latent is placed from half its touches (:func:`place_latent`, the model
fixed) and the other half is scored at it (:func:`log_densities_at`), then the halves swap.

Pure maths.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from core.errors import InvalidInputError
from core.gp.posterior import predict_model_space
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray, IntArray, as_float_array

#: Local optimisations of a held-out latent, started from the best-scoring training latents.
PLACEMENT_STARTS = 3


def object_folds(n_objects: int, n_folds: int, rng: np.random.Generator) -> IntArray:
    """Fold of every object: the objects shuffled and dealt round-robin to K folds.

    Args:
        n_objects: L ≥ 3 (every training set needs at least 2 objects).
        n_folds: K, 2 ≤ K ≤ L; with L = K every object is its own fold.
        rng: Random generator (the shuffle).

    Returns:
        Fold of every object, 0..K-1. Shape (L,).

    Raises:
        InvalidInputError: K < 2, K > L, or a training set with fewer than 2 objects.
    """
    if int(n_folds) < 2 or int(n_folds) > int(n_objects):
        raise InvalidInputError(
            f"n_folds: leave-objects-out needs 2 ≤ K ≤ L = {n_objects} objects, received {n_folds}."
        )
    largest_fold = -(-int(n_objects) // int(n_folds))
    if int(n_objects) - largest_fold < 2:
        raise InvalidInputError(
            f"leave-objects-out with {n_folds} folds of {n_objects} objects leaves "
            f"{int(n_objects) - largest_fold} training object(s); at least 2 are needed "
            f"(use more objects or more folds)."
        )
    folds = np.empty(int(n_objects), dtype=np.int64)
    folds[rng.permutation(int(n_objects))] = np.arange(int(n_objects)) % int(n_folds)
    return folds


def split_halves(object_index: IntArray, rng: np.random.Generator) -> IntArray:
    """Half (0 or 1) of every touch: each object's touches shuffled and dealt alternately.

    Args:
        object_index: Object of every touch; every object needs ≥ 2 touches. Shape (N,).
        rng: Random generator (the shuffle).

    Returns:
        0 or 1 per touch; each object's halves differ in size by at most one. Shape (N,).
    """
    index = np.asarray(object_index, dtype=np.int64)
    halves = np.empty(index.shape[0], dtype=np.int64)
    for obj in np.unique(index):
        touches = np.flatnonzero(index == obj)
        if touches.shape[0] < 2:
            raise InvalidInputError(
                f"object {int(obj)} has {touches.shape[0]} touch(es); placing and scoring a "
                f"held-out object needs at least 2."
            )
        halves[rng.permutation(touches)] = np.arange(touches.shape[0]) % 2
    return halves


def log_densities_at(
    model: ManifoldModel, latent: FloatArray, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """log p(y_t | s, x_t) of touches of one object at latent s, in raw units.

    Σ_a log N(y'_a; m_a, v_a) + log|det M| (the same density as
    :func:`core.recognition.object_posterior.touch_log_likelihoods`, at any latent).

    Args:
        model: A conditioned model.
        latent: s. Shape (ds,).
        actions: Actions. Shape (t, dx).
        observations: Raw observations. Shape (t, dy).

    Returns:
        Log-density of each touch. Shape (t,).
    """
    h = model.hyperparameters
    s = as_float_array(latent, "latent", (h.latent_dim,))
    x = as_float_array(actions, "actions", (None, h.action_dim))
    y = as_float_array(observations, "observations", (x.shape[0], h.observation_dim))
    mean, variance = predict_model_space(model, np.broadcast_to(s, (x.shape[0], s.shape[0])), x)
    residual = model.to_model_space(y) - mean
    log_density = -0.5 * (np.log(2.0 * np.pi * variance) + residual**2 / variance)
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    return np.asarray(log_density.sum(axis=1) + jacobian, dtype=np.float64)


def place_latent(model: ManifoldModel, actions: FloatArray, observations: FloatArray) -> FloatArray:
    """The maximum-likelihood latent of a new object from some of its touches.

    argmax_s Σ_t log p(y_t | s, x_t) with the model (hyperparameters, training latents) fixed:
    the objective is evaluated at every training latent, and L-BFGS-B runs from the
    :data:`PLACEMENT_STARTS` best of them; the best end point is returned.

    Args:
        model: A conditioned model.
        actions: Actions of the placement touches. Shape (t, dx).
        observations: Their raw observations. Shape (t, dy).

    Returns:
        s. Shape (ds,).
    """

    def negative(s: FloatArray) -> float:
        return -float(log_densities_at(model, s, actions, observations).sum())

    starts = np.asarray(model.latents, dtype=np.float64)
    values = np.array([negative(s) for s in starts])
    best_s = starts[int(np.argmin(values))]
    best_value = float(values.min())
    for start in starts[np.argsort(values)[:PLACEMENT_STARTS]]:
        result = scipy.optimize.minimize(negative, start, method="L-BFGS-B")
        if float(result.fun) < best_value:
            best_s, best_value = np.asarray(result.x, dtype=np.float64), float(result.fun)
    return np.asarray(best_s, dtype=np.float64)


def objects_subset(data: TrainingData, objects: IntArray) -> TrainingData:
    """The touches of ``objects`` as a training set of their own (objects renumbered)."""
    renumber = np.full(data.n_objects, -1, dtype=np.int64)
    renumber[objects] = np.arange(objects.shape[0])
    keep = np.flatnonzero(np.isin(data.object_index, objects))
    return TrainingData(
        object_names=tuple(data.object_names[int(o)] for o in objects),
        object_index=renumber[data.object_index[keep]],
        actions=data.actions[keep],
        observations=data.observations[keep],
    )


def held_out_scores(
    model: ManifoldModel, data: TrainingData, held_objects: IntArray, halves: IntArray
) -> FloatArray:
    """Log-density of every touch of the held-out objects, each placed from its other half.

    Args:
        model: Fitted without ``held_objects``.
        data: All touches.
        held_objects: Objects held out (indices into ``data``). Shape (h,).
        halves: Half of every touch of ``data`` (:func:`split_halves`). Shape (N,).

    Returns:
        One log-density per touch of the held-out objects, in the order of
        ``np.flatnonzero(np.isin(data.object_index, held_objects))``. Shape (t,).
    """
    touches = np.flatnonzero(np.isin(data.object_index, held_objects))
    scores = np.empty(touches.shape[0])
    for obj in held_objects:
        for half in (0, 1):
            place = np.flatnonzero((data.object_index == obj) & (halves == half))
            score = np.flatnonzero((data.object_index == obj) & (halves != half))
            s = place_latent(model, data.actions[place], data.observations[place])
            values = log_densities_at(model, s, data.actions[score], data.observations[score])
            scores[np.searchsorted(touches, score)] = values
    return scores
