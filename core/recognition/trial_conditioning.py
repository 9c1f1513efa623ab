"""The next touch given the trial's touches so far, under each learned object.

The object posterior scores a trial's touches jointly (docs/calibration.md eq. (C3)): under object
l, per model-space feature a, the T touches are one Gaussian

    y_a ~ N(m_a(s_l, X), V_a(s_l; X, X) + σ_sh,a² 11ᵀ + (σ_n,a² − σ_sh,a²) I),

with V_a the GP's posterior covariance of f_a between the touches (:mod:`core.gp.cross_covariance`)
and σ_sh² the variance of the offset they share (the placement's and the drift's,
:func:`core.recognition.object_posterior.shared_variance`). The next touch at x belongs to the same
Gaussian, so under l it is predicted by the conditional

    y_a(x) | l, D_T ~ N(m_a(s_l, x) + cᵀ A⁻¹ r,  v_a(s_l, x) − cᵀ A⁻¹ c),
    A = the T × T covariance above,  c = V_a(s_l; X, x) + σ_sh,a² 1,  r = y'_a − m_a(s_l, X),

v_a the touch's own predictive variance with noise (docs/method.md, "The next touch given the
trial's touches"). A planner that used the unconditional predictive instead would value a repeat
of an action as much as its first touch, although under l the repeat's offset and f are already
seen: on a table whose placement offsets are large it kept touching one action (measured in
docs/calibration.md). This module gives the two corrections, the mean shift cᵀ A⁻¹ r and the
variance reduction cᵀ A⁻¹ c, for every candidate, object and feature; the discriminative policy
and the mixture the active policy plans under apply them to their per-object predictives.

The learned latents are taken as points here (a model with latent uncertainty integrates them in
its object posterior, not in these corrections).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.gp.cross_covariance import object_cross_covariances
from core.gp.linalg import cholesky_with_jitter
from core.gp.placement_effect import check_placement_variance
from core.gp.posterior import predict_model_space
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array

__all__ = ["TrialCorrections", "TrialTouches", "conditioned_predictives", "trial_corrections"]


@dataclass(frozen=True)
class TrialTouches:
    """The touches a trial has made so far, and the offset variance they share.

    Attributes:
        actions: x_1..x_T. Shape (T, dx), T ≥ 1.
        observations: Their raw observations. Shape (T, dy).
        shared_variance: σ_sh², model space, each in [0, σ_n²): the placement's (when the
            touches met one placement) plus the drift's; zeros when they share neither.
            Shape (dy,).
    """

    actions: FloatArray
    observations: FloatArray
    shared_variance: FloatArray

    def __post_init__(self) -> None:
        actions = as_float_array(self.actions, "trial actions", (None, None))
        if actions.shape[0] < 1:
            raise InvalidInputError("trial actions: need at least one touch.")
        observations = as_float_array(
            self.observations, "trial observations", (actions.shape[0], None)
        )
        shared = as_float_array(self.shared_variance, "shared variance", (observations.shape[1],))
        checked = {"actions": actions, "observations": observations, "shared_variance": shared}
        for name, array in checked.items():
            kept = array.copy()
            kept.flags.writeable = False
            object.__setattr__(self, name, kept)


@dataclass(frozen=True)
class TrialCorrections:
    """What the trial's touches change in each object's predictive of the next touch.

    Attributes:
        shift: cᵀ A⁻¹ r, added to the predictive mean (model space). Shape (C, L, dy).
        reduction: cᵀ A⁻¹ c, taken from the predictive variance. Shape (C, L, dy).
        within_variance: σ_n² − σ_sh², the part of each touch's noise no other touch shares: a
            conditional variance never falls below it. Shape (dy,).
    """

    shift: FloatArray
    reduction: FloatArray
    within_variance: FloatArray

    def conditional_variance(self, variance: FloatArray) -> FloatArray:
        """The conditional of a predictive variance (C, L, dy) that includes the noise:
        variance − reduction, kept at or above ``within_variance``."""
        return np.maximum(variance - self.reduction, self.within_variance)


def trial_corrections(
    model: ManifoldModel, trial: TrialTouches, candidates: FloatArray
) -> TrialCorrections:
    """The mean shift and variance reduction of the next touch at each candidate (module docstring).

    Cost: O(dy · L · T · N · (N + C)) for the GP cross-covariances, then O(dy · L · T² · C).

    Args:
        model: A conditioned model.
        trial: The trial's touches so far.
        candidates: The actions the next touch may take. Shape (C, dx).

    Raises:
        InvalidInputError: Shapes that do not match the model, or a shared variance outside
            [0, σ_n²).
    """
    h = model.hyperparameters
    x = as_float_array(trial.actions, "trial actions", (None, h.action_dim))
    y = as_float_array(trial.observations, "trial observations", (x.shape[0], h.observation_dim))
    others = as_float_array(candidates, "candidates", (None, h.action_dim))
    shared = check_placement_variance(model, trial.shared_variance)
    within = h.noise_variance - shared
    n_objects, t = model.latents.shape[0], x.shape[0]
    y_model = model.to_model_space(y)
    mean, _ = predict_model_space(
        model, np.repeat(model.latents, t, axis=0), np.tile(x, (n_objects, 1))
    )
    residuals = y_model[None, :, :] - mean.reshape(n_objects, t, h.observation_dim)  # (L, T, dy)
    both = object_cross_covariances(model, x, np.vstack([x, others]))  # (L, dy, T, T + C)
    among, towards = both[..., :t], both[..., t:]
    shift = np.empty((others.shape[0], n_objects, h.observation_dim))
    reduction = np.empty_like(shift)
    for obj in range(n_objects):
        for a in range(h.observation_dim):
            cov = among[obj, a]
            joint = 0.5 * (cov + cov.T) + shared[a] + within[a] * np.eye(t)
            factor, _ = cholesky_with_jitter(joint, what=f"trial covariance of feature {a}")
            cross = towards[obj, a] + shared[a]  # (T, C)
            whitened = scipy.linalg.solve_triangular(
                factor,
                np.column_stack([residuals[obj, :, a], cross]),
                lower=True,
                check_finite=False,
            )
            shift[:, obj, a] = whitened[:, 1:].T @ whitened[:, 0]
            reduction[:, obj, a] = np.sum(whitened[:, 1:] ** 2, axis=0)
    return TrialCorrections(shift=shift, reduction=reduction, within_variance=within)


def conditioned_predictives(
    model: ManifoldModel,
    trial: TrialTouches | None,
    actions: FloatArray,
    mean: FloatArray,
    variance: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Each object's predictive at ``actions`` given the trial's touches (unchanged for ``None``).

    Args:
        model: A conditioned model.
        trial: The trial's touches so far, or ``None``.
        actions: The candidates. Shape (C, dx).
        mean: Their unconditional predictive means, model space. Shape (C, L, dy).
        variance: Their predictive variances with noise. Shape (C, L, dy).

    Returns:
        The conditional means and variances, shapes as given.
    """
    if trial is None:
        return mean, variance
    corrections = trial_corrections(model, trial, actions)
    if corrections.shift.shape != np.shape(mean):
        raise InvalidInputError(
            f"mean: expected shape {corrections.shift.shape} for these candidates, received "
            f"{np.shape(mean)}."
        )
    return mean + corrections.shift, corrections.conditional_variance(variance)
