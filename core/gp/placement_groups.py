"""Touches that share a placement, and the covariance their shared offset adds.

A placement is one (object, placement number) pair of :class:`core.types.TrainingData`: the
object was set down once and touched several times, so those touches share an offset b_a ~
N(0, σ_b,a²) (docs/calibration.md, eq. (C1)). In the training covariance of feature a that is

    K_a = K_f,a + σ_b,a² Z Zᵀ + (σ_n,a² − σ_b,a²) I,

Z the N × G placement indicator: σ_n,a² stays each touch's whole noise variance and σ_b,a² moves
to the off-diagonal entries of pairs sharing a placement. Only placements with two or more
touches add anything; without recorded placements K_a is the independent-noise matrix of (M1).
"""

from __future__ import annotations

import numpy as np

from core.errors import InvalidInputError
from core.validation import FloatArray, IntArray, as_float_array


def placement_groups(object_index: IntArray, placement_index: IntArray) -> list[IntArray]:
    """Touch indices of every placement, a placement being one (object, placement number).

    Args:
        object_index: Object of every touch. Shape (N,).
        placement_index: Placement number of every touch. Shape (N,).

    Returns:
        One index array per placement, in order of first appearance.
    """
    keys = np.stack([np.asarray(object_index), np.asarray(placement_index)], axis=1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first)
    return [np.flatnonzero(inverse == g) for g in order]


def shared_groups(object_index: IntArray, placement_index: IntArray | None) -> list[IntArray]:
    """The placements with at least two touches (the only ones that add covariance).

    Args:
        object_index: Object of every touch. Shape (N,).
        placement_index: Placement number of every touch, or ``None`` (none recorded). Shape (N,).

    Returns:
        Touch indices of each such placement; empty without recorded placements.
    """
    if placement_index is None:
        return []
    return [g for g in placement_groups(object_index, placement_index) if g.size >= 2]


def add_shared_offsets(gram: FloatArray, groups: list[IntArray], variance: float) -> None:
    """Add σ_b² to every off-diagonal entry (i, j ≠ i) of ``gram`` whose touches share a
    placement, in place: K + σ_b² (Z Zᵀ − I) restricted to the groups.

    Args:
        gram: A symmetric matrix over the touches. Shape (N, N).
        groups: Touch indices of each placement (:func:`shared_groups`).
        variance: σ_b² ≥ 0.
    """
    if variance == 0.0:
        return
    for group in groups:
        block = np.ix_(group, group)
        gram[block] += variance
        gram[group, group] -= variance


def checked_placement_variance(
    variance: object, noise_variance: FloatArray | None, observation_dim: int
) -> FloatArray:
    """σ_b² as dy checked values: ≥ 0, and below each feature's σ_n,a² when ``noise_variance`` is
    given (σ_b,a² is then a part of the touch's noise variance, so σ_w,a² = σ_n,a² − σ_b,a² > 0).

    Args:
        variance: σ_b,a² per feature. Shape (dy,).
        noise_variance: σ_n,a² per feature, or ``None`` (σ_w,a² is fitted beside σ_b,a²).
            Shape (dy,).
        observation_dim: dy.

    Returns:
        The values as a float array. Shape (dy,).

    Raises:
        InvalidInputError: Wrong length, not finite, negative, or not below σ_n,a².
    """
    value = as_float_array(variance, "placement_variance", (observation_dim,))
    if noise_variance is None:
        if np.any(value < 0.0):
            raise InvalidInputError(
                f"placement_variance: every σ_b,a² must be ≥ 0, received {value.tolist()}."
            )
    elif np.any(value < 0.0) or np.any(value >= noise_variance):
        raise InvalidInputError(
            f"placement_variance: every σ_b,a² must lie in [0, σ_n,a²) = [0, "
            f"{np.asarray(noise_variance).tolist()}), received {value.tolist()}."
        )
    return value
