"""Each object's own placement variance: how much one placement shifts *this* object's touches.

The placement effect σ_b² (:mod:`core.gp.placement_effect`) is pooled over the objects. On a
rig it is not one number: a placement moves the contact point, and what that does to a touch
depends on the object — a stiff plate's force changes with the contact angle, a soft cloth's
hardly at all. A pooled σ_b² then discounts the evidence of a trial on the cloth too much (its
answers come out less sure than they are right) and on the plate too little (docs/calibration.md,
"Each object's placement variance").

Every placement's term of the method-of-moments sum
(:func:`core.gp.placement_effect.placement_moments`) belongs to one object, so each object has
its own estimate

    σ̂_l,a² = Σ_{G of l} c_G,a / Σ_{G of l} n_G (n_G − 1)   (+ the σ_b,0² in the fit),

with a standard error se_l,a from the spread of its placements' terms (cluster-robust: the terms
of different placements are independent, the pairs within one are not). With a few dozen
placements per object it is noisy, so each is shrunk towards the model's pooled σ_b,a² (μ_a) by
how far the objects truly differ, per feature:

    τ_a² = max(0, var_l(σ̂_l,a²) − mean_l(se_l,a²)),
    σ_b,l,a² = μ_a + τ_a² / (τ_a² + se_l,a²) · (σ̂_l,a² − μ_a),

τ_a² the method-of-moments between-object variance with equal weights (a variance estimate's
standard error grows with the variance, so inverse-variance weights would favour the small
estimates and pull τ² down). With no spread beyond the sampling noise every object gets the
pooled value; an object whose placements clearly differ keeps most of its own. Each is clipped
to [0, :func:`object_placement_ceiling`], so a trial's shared offset stays below each touch's
noise. Every touch keeps its own predictive density: only how much of its noise a trial's touches
share changes with the object (docs/calibration.md (C3) with σ_b,l² in place of σ_b²). The
training covariance keeps the pooled σ_b²: this scores trials only.

Not adopted (off unless asked, :func:`core.recognition.calibrate`): on the unseen workshop table
it cost every policy 12-18 points of accuracy at touch 6. From 25 placements of two touches per
object the estimates differ between look-alike objects by more than they truly do, and a trial's
likelihood reads the difference as evidence: a trial whose touches share an offset is given to
the look-alike with the larger σ_b,l² (docs/calibration.md, "Each object's placement variance").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.gp.placement_effect import (
    MAX_PLACEMENT_FRACTION,
    object_moment_estimates,
    placement_moments,
)
from core.types import ManifoldModel
from core.validation import FloatArray, IntArray, as_float_array


@dataclass(frozen=True)
class ObjectPlacementEstimate:
    """Each object's placement variance (:func:`estimate_object_placement_variance`).

    Attributes:
        variance: σ_l,a², shrunk and clipped, model space. Shape (L, dy).
        raw_variance: σ̂_l,a², each object's own moment estimate (NaN without two placements
            of two touches). Shape (L, dy).
        standard_error: se_l,a of σ̂_l,a² (inf without two such placements). Shape (L, dy).
        between_variance: τ_a², the spread of the objects' true values. Shape (dy,).
        mean: μ_a, the pooled σ_b² the objects' estimates are shrunk towards. Shape (dy,).
        placements: Placements of two touches or more of each object. Shape (L,).
    """

    variance: FloatArray
    raw_variance: FloatArray
    standard_error: FloatArray
    between_variance: FloatArray
    mean: FloatArray
    placements: IntArray


def estimate_object_placement_variance(
    model: ManifoldModel, placement_index: IntArray
) -> ObjectPlacementEstimate | None:
    """σ_b,l,a² of every object from its placements' leave-one-placement-out residuals.

    Args:
        model: A fitted model (its pooled σ_b², if in its training covariance, is accounted
            for as in :func:`core.gp.placement_effect.estimate_placement_variance`).
        placement_index: Placement number of every training touch. Shape (N,), integers.

    Returns:
        The estimate, or ``None`` when fewer than two objects have two placements of two
        touches or more (nothing to tell the objects apart by).

    Raises:
        InvalidInputError: ``placement_index`` is not N integers.
    """
    placement = np.asarray(placement_index)
    n_touches = model.data.n_touches
    if placement.shape != (n_touches,) or not np.issubdtype(placement.dtype, np.integer):
        raise InvalidInputError(
            f"placement_index: expected {n_touches} integers, received dtype {placement.dtype} "
            f"with shape {placement.shape}."
        )
    moments = placement_moments(model, placement)
    n_objects = model.data.n_objects
    dy = model.hyperparameters.observation_dim
    error = np.full((n_objects, dy), np.inf)
    counts = np.bincount(moments.objects, minlength=n_objects)
    raw = object_moment_estimates(moments, n_objects)
    raw[counts < 2] = np.nan  # no standard error from one placement
    for obj in np.flatnonzero(counts >= 2):
        mine = moments.objects == obj
        terms, pairs = moments.contributions[mine], moments.pairs[mine].astype(np.float64)
        total = pairs.sum()
        spread = terms - np.outer(pairs, (raw[obj] - moments.in_fit))
        m = int(mine.sum())
        error[obj] = np.sqrt(m / (m - 1) * np.sum(spread**2, axis=0)) / total
    known = np.flatnonzero(counts >= 2)
    if known.size < 2:
        return None
    pooled = moments.contributions.sum(axis=0) / moments.pairs.sum() + moments.in_fit
    if model.placement_variance is not None:
        pooled = np.asarray(model.placement_variance, dtype=np.float64)
    between, mean = _random_effects(raw[known], error[known], np.maximum(pooled, 0.0))
    # between / (between + se²): 0 without an estimate (se = inf), 1 for an exact one (se = 0).
    spread = between + np.where(np.isfinite(error), error**2, np.inf)
    weight = np.divide(between, spread, out=np.ones_like(error), where=spread > 0)
    shrunk = mean + weight * (np.nan_to_num(raw) - mean)
    upper = object_placement_ceiling(model, mean)
    return ObjectPlacementEstimate(
        variance=np.clip(shrunk, 0.0, upper),
        raw_variance=raw,
        standard_error=error,
        between_variance=between,
        mean=mean,
        placements=counts.astype(np.int64),
    )


def object_placement_ceiling(model: ManifoldModel, pooled: FloatArray) -> FloatArray:
    """The largest σ_b,l,a² an object may have: MAX_PLACEMENT_FRACTION of what σ_n,a² leaves
    beside the drift's σ_d,a², or the pooled σ_b,a² if that is larger (it was checked below
    σ_n,a² − σ_d,a² already), so that a trial's shared offset stays below each touch's noise.
    Shape (dy,)."""
    h = model.hyperparameters
    drift = np.zeros(h.observation_dim) if model.drift_variance is None else model.drift_variance
    return np.maximum(MAX_PLACEMENT_FRACTION * (h.noise_variance - drift), pooled)


def with_object_placement(
    model: ManifoldModel,
) -> tuple[ManifoldModel, ObjectPlacementEstimate | None]:
    """The model with each object's placement variance, when its training touches record
    placements and it has a pooled placement effect (run after
    :func:`core.gp.placement_effect.with_placement_effect` and the drift); unchanged and
    ``None`` otherwise."""
    placement = model.raw_data.placement_index
    if placement is None or model.placement_variance is None:
        return model, None
    estimate = estimate_object_placement_variance(model, placement)
    if estimate is None:
        return model, None
    return dataclasses.replace(model, object_placement_variance=estimate.variance), estimate


def check_object_placement_variance(model: ManifoldModel, variance: object) -> FloatArray:
    """σ_b,l,a² as a checked array: L × dy values ≥ 0 whose sum with the drift's σ_d,a² stays
    below σ_n,a², for a model with a pooled placement effect. Shape (L, dy).

    Raises:
        InvalidInputError: Wrong shape, not finite, negative, above the noise, or a model
            without a pooled placement effect.
    """
    h = model.hyperparameters
    value = as_float_array(
        variance, "object_placement_variance", (model.latents.shape[0], h.observation_dim)
    )
    if model.placement_variance is None:
        raise InvalidInputError(
            "object_placement_variance: the model has no pooled placement effect to go with it."
        )
    drift = np.zeros(h.observation_dim) if model.drift_variance is None else model.drift_variance
    if np.any(value < 0.0) or np.any(value + drift >= h.noise_variance):
        raise InvalidInputError(
            "object_placement_variance: every σ_b,l,a² must be ≥ 0 with σ_b,l,a² + σ_d,a² below "
            f"σ_n,a² = {h.noise_variance.tolist()}, received {value.tolist()}."
        )
    return value


def _random_effects(
    estimates: FloatArray, errors: FloatArray, pooled: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """τ² by the unweighted method of moments, and the mean to shrink towards (the pooled
    estimate), per column. Shapes (k, dy), (k, dy), (dy,) → (dy,), (dy,).

    The objects' estimates are weighted equally: a variance estimate's standard error grows with
    the variance, so inverse-variance weights would favour the small ones and pull τ² and the
    mean down.
    """
    spread = np.var(estimates, axis=0, ddof=1)
    between = np.maximum(0.0, spread - np.mean(errors**2, axis=0))
    return between, np.asarray(pooled, dtype=np.float64)
