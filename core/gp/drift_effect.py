"""The drift effect: the slow drift of sensor and room, shared by touches made close in time.

A fingertip's heater and the room's temperature wander over minutes; so does a pressure baseline.
Every touch made in those minutes is shifted alike, whatever the object. A trial's T touches are
made within a minute or two, so they share one drift offset, like the offset of one placement
(:mod:`core.gp.placement_effect`), and the object likelihood has to count it once, not T times
(docs/calibration.md, "The drift effect"). Per model-space feature a:

    y_ta = f_a(s_l, x_t) + b_a + d_a + ε_ta,   d_a ~ N(0, σ_d,a²) once per trial,

with σ_n,a² = σ_b,a² + σ_d,a² + σ_w,a² each touch's whole noise variance (the convention of
docs/calibration.md (C2): a single touch's predictive density is unchanged, the shared part only
stops being counted once per touch).

σ_d² is estimated from a collection that records when each touch was made
(``TrainingData.touch_times_s``): leave-one-out residuals of touches of **different objects** made
within ``window_s`` of each other share the drift and nothing else the model does not already
have (no placement, no object), so their excess covariance over the fitted model's is σ_d²
(:func:`estimate_drift_variance`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.gp.linalg import cholesky_with_jitter
from core.gp.placement_effect import MAX_PLACEMENT_FRACTION
from core.gp.posterior import gram_matrix
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array

#: The window, in gaps between consecutive touches of the collection: the span of a six-touch
#: trial made at the collection's pace.
WINDOW_GAPS = 5

__all__ = [
    "WINDOW_GAPS",
    "DriftEstimate",
    "check_drift_variance",
    "default_window_s",
    "estimate_drift_variance",
    "with_drift_effect",
]


@dataclass(frozen=True)
class DriftEstimate:
    """σ_d² estimated from touches made close in time (:func:`estimate_drift_variance`).

    Attributes:
        variance: σ_d,a², model space, after clipping to
            [0, MAX_PLACEMENT_FRACTION · σ_n,a² − σ_b,a²]. Shape (dy,).
        raw_variance: The moment estimate before clipping (may be negative). Shape (dy,).
        window_s: Touches at most this far apart in time formed the pairs.
        pairs: Unordered pairs of touches of different objects within the window.
    """

    variance: FloatArray
    raw_variance: FloatArray
    window_s: float
    pairs: int


def default_window_s(times_s: FloatArray) -> float:
    """:data:`WINDOW_GAPS` median gaps between consecutive touches (in time order): the time a
    six-touch trial takes at the pace the collection was made.

    Args:
        times_s: When each touch was made. Shape (N,), N ≥ 2.

    Raises:
        InvalidInputError: Fewer than two touches, or every touch at one time.
    """
    times = np.sort(as_float_array(times_s, "touch_times_s", (None,)))
    gaps = np.diff(times)
    if gaps.size == 0 or not np.any(gaps > 0):
        raise InvalidInputError(
            f"touch_times_s: the drift needs touches made at different times, received "
            f"{times.size} touch(es) at {np.unique(times).size} distinct time(s)."
        )
    return float(WINDOW_GAPS * np.median(gaps[gaps > 0]))


def estimate_drift_variance(
    model: ManifoldModel, times_s: FloatArray, window_s: float | None = None
) -> DriftEstimate:
    """σ_d,a² from the leave-one-out residuals of training touches made close in time.

    Touch i left out, the GP conditioned on the others predicts y_i with residual
    r_i = β_i / (K⁻¹)_ii, and under the fitted model Cov(r_i, r_j) = C_ij = (K⁻¹)_ij /
    ((K⁻¹)_ii (K⁻¹)_jj) (GPML §5.4.2; K the noisy Gram matrix with the model's own placement
    offsets, β = K⁻¹ (y − mean)). Two touches of different objects made within ``window_s`` of
    each other share the drift offset and, under the model, nothing it lacks, so E[r_i r_j] =
    C_ij + σ_d² and the method-of-moments estimate pools every such pair:

        σ_d,a² = Σ_{(i,j)} (r_i r_j − C_ij) / #pairs,

    clipped to [0, MAX_PLACEMENT_FRACTION · σ_n,a² − σ_b,a²] so that the touch's own noise σ_w²
    stays positive. The GP's own uncertainty is subtracted (C_ij). Touches of one object are left
    out of the pairs: they also share their object's error and their placement.

    Args:
        model: A model fitted on the touches (the Gram matrices are rebuilt here, O(N³) per
            feature).
        times_s: When each training touch was made, seconds on one clock. Shape (N,).
        window_s: Pair touches at most this far apart; ``None``: :func:`default_window_s`.

    Returns:
        The estimate; ``variance`` is zero when no pair falls in the window.

    Raises:
        InvalidInputError: ``times_s`` is not N finite numbers, or ``window_s`` is not > 0.
    """
    data = model.data
    times = as_float_array(times_s, "touch_times_s", (data.n_touches,))
    window = default_window_s(times) if window_s is None else float(window_s)
    if not np.isfinite(window) or window <= 0:
        raise InvalidInputError(f"window_s: must be > 0, received {window_s}.")
    h = model.hyperparameters
    dy = h.observation_dim
    obj = data.object_index
    upper_i, upper_j = np.triu_indices(data.n_touches, k=1)
    close = (np.abs(times[upper_i] - times[upper_j]) <= window) & (obj[upper_i] != obj[upper_j])
    pair_i, pair_j = upper_i[close], upper_j[close]
    placement = model.placement_variance
    shared = np.zeros(dy) if placement is None else np.asarray(placement, dtype=np.float64)
    if pair_i.size == 0:
        zero = np.zeros(dy)
        return DriftEstimate(variance=zero, raw_variance=zero.copy(), window_s=window, pairs=0)
    in_fit = placement if model.placement_in_fit else None
    centred = data.observations - data.observation_mean
    identity = np.eye(data.n_touches)
    raw = np.empty(dy)
    for a in range(dy):
        factor, _ = cholesky_with_jitter(
            gram_matrix(data, model.latents, h, a, in_fit), what=f"Gram matrix of feature {a}"
        )
        inverse = scipy.linalg.cho_solve((factor, True), identity, check_finite=False)
        diagonal = np.diag(inverse)
        residual = (inverse @ centred[:, a]) / diagonal
        expected = inverse[pair_i, pair_j] / (diagonal[pair_i] * diagonal[pair_j])
        raw[a] = float(np.mean(residual[pair_i] * residual[pair_j] - expected))
    upper = np.maximum(MAX_PLACEMENT_FRACTION * h.noise_variance - shared, 0.0)
    variance = np.clip(raw, 0.0, upper)
    pairs = int(pair_i.size)
    return DriftEstimate(variance=variance, raw_variance=raw, window_s=window, pairs=pairs)


def with_drift_effect(model: ManifoldModel) -> tuple[ManifoldModel, DriftEstimate | None]:
    """The model with the drift effect of its training touches, if they record their times.

    σ_d² (:func:`estimate_drift_variance`, default window) is split off each touch's noise for
    scoring trials (the fit is left as it is: its σ_n² already holds the drift its training
    touches saw). Run it after :func:`core.gp.placement_effect.with_placement_effect`, so that
    the placements' offsets are in the model the residuals are taken under.

    Returns:
        The model and the estimate; the model unchanged and ``None`` when the training touches
        have no times, or no two touches of different objects fall in the window.
    """
    times = model.raw_data.touch_times_s
    if times is None:
        return model, None
    estimate = estimate_drift_variance(model, times)
    if estimate.pairs == 0:
        return model, None
    return dataclasses.replace(model, drift_variance=estimate.variance), estimate


def check_drift_variance(model: ManifoldModel, variance: object) -> FloatArray:
    """σ_d² as a checked array: dy values ≥ 0 whose sum with the model's σ_b² stays below σ_n²
    (the touch keeps a noise of its own). Shape (dy,).

    Raises:
        InvalidInputError: Wrong length, not finite, negative, or σ_b² + σ_d² not below σ_n².
    """
    h = model.hyperparameters
    value = as_float_array(variance, "drift_variance", (h.observation_dim,))
    placement = model.placement_variance
    shared = value if placement is None else value + placement
    if np.any(value < 0.0) or np.any(shared >= h.noise_variance):
        raise InvalidInputError(
            f"drift_variance: every σ_d,a² must be ≥ 0 with σ_b,a² + σ_d,a² below σ_n,a² = "
            f"{h.noise_variance.tolist()}, received {value.tolist()}."
        )
    return value
