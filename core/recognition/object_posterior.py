"""The discrete posterior over the L learned objects given the touches so far.

Kept alongside the Gaussian belief of docs/method.md (M5): the Gaussian is a local, moment-matched
approximation that can settle near the wrong object; this posterior uses the exact GP predictive
likelihood of every touch under every learned object and does not (docs/method.md, "A known failure
mode" and "Recommended defaults: Decision").

By default the touches of a trial are scored as one joint Gaussian per object (``"joint"``,
docs/calibration.md eq. (C3)): given s_l they share the same uncertain function f, so the GP
posterior's full covariance V of f at the trial's actions enters once, not once per touch; a model
with a placement effect (``model.placement_variance`` > 0, estimated from a collection that
recorded placements: :mod:`core.gp.placement_effect`) adds the placement's shared offset when the
touches share one placement. ``"independent"`` keeps the product of independent per-touch
densities (the base model of docs/method.md (M1)). Every caller — the recognition session's
answer, stop rule, re-centring and the discriminative policy's probabilities — goes through
:func:`object_log_likelihoods`.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from core.errors import InvalidInputError
from core.gp.placement_effect import trial_log_likelihoods
from core.gp.posterior import predict_model_space
from core.recognition.latent_uncertainty import (
    trial_log_likelihoods as latent_trial_log_likelihoods,
)
from core.types import ManifoldModel
from core.validation import FloatArray, IntArray, as_float_array

TrialLikelihood = Literal["joint", "independent"]

#: Every way of scoring a trial's touches (:func:`object_log_likelihoods`).
TRIAL_LIKELIHOODS: tuple[TrialLikelihood, ...] = ("joint", "independent")


def object_log_likelihoods(
    model: ManifoldModel,
    actions: FloatArray,
    observations: FloatArray,
    trial_likelihood: TrialLikelihood = "joint",
    shared_placement: bool = True,
) -> FloatArray:
    """log p(D_t | l) of one trial's touches D_t under every learned object l.

    ``"joint"`` (default): under object l the touches are one Gaussian per model-space feature
    (docs/calibration.md eq. (C3), :func:`core.gp.placement_effect.trial_log_likelihoods`),

        y'_·a ~ N(m_a(s_l, X), V_a(s_l, X) + σ_b,a² 11ᵀ + (σ_n,a² − σ_b,a²) I),

    with V_a the GP posterior's full T × T covariance of f_a at (s_l, x_1..x_T) (GPML eq. 2.24):
    the touches share the same uncertain f, so its uncertainty counts once, not once per touch.
    σ_b² is the model's placement variance when it has one and ``shared_placement`` (the touches
    met one placement of the object), else 0. It is not a sum over touches: pass all of a
    trial's touches at once. For one touch it equals the independent density below.

    A model with ``latent_covariance`` (the Laplace covariance Σ_l of every object's latent,
    :mod:`core.recognition.latent_uncertainty`) integrates each s_l over N(s_l, Σ_l) instead of
    taking it as known (docs/method.md (L2)–(L3)): the moments above become the Gaussian-input
    moments over all touches and features at once, in either setting.

    A model with ``shift_variance`` σ_δ² (:mod:`core.gp.input_shift`) adds, under object l, the
    covariance J_l(x_t) diag(σ_δ² + σ_c² min(t, u)) J_l(x_u)ᵀ of a placement's shift of the
    action (σ_c², ``shift_creep_variance``, its creep from touch to touch), J_l the slope of the
    predictive mean at s_l: between every pair of touches when they met one placement
    (``shared_placement``, the touches in the order they were made), within each touch
    otherwise. ``"joint"`` only.

    A model with ``tempering`` = β (:mod:`core.recognition.tempering`, a last resort fitted on the
    training touches) returns β times the value: the posterior becomes p(D_t | l)^β, normalised.

    ``"independent"``: the touches are independent given the object (the base model, (M1)):

        log p(D_t | l) = Σ_t [Σ_a log N(y'_ta; m_a(s_l, x_t), v_a(s_l, x_t) + σ_n,a²) + log|det M|].

    The observations come in raw units and are mapped to the model space y' = M (y - c) of the
    model's observation transform (the identity for a model without one); m_a and v_a are the
    GP predictive mean and variance of f_a at the learned latent s_l and action x_t
    (:func:`core.gp.posterior.predict_model_space`, which adds the noise variance). The features of
    y' are independent given (s, x); the Jacobian log|det M| (= -½ log det Σ_ε, docs/method.md "Real
    tactile data") makes the value a log-density of the raw observations.

    Args:
        model: A conditioned model.
        actions: Actions x_t of the touches. Shape (t, dx).
        observations: Raw observations y_t. Shape (t, dy).
        trial_likelihood: ``"joint"`` or ``"independent"``.
        shared_placement: Whether the touches met one placement (σ_b² applies; ``"joint"`` only).

    Returns:
        Log-likelihood of the touches under each object. Shape (L,).

    Raises:
        InvalidInputError: Wrong shapes, non-finite values or an unknown ``trial_likelihood``.
    """
    values = _untempered_log_likelihoods(
        model, actions, observations, trial_likelihood, shared_placement
    )
    if model.tempering is None:
        return values
    # A last resort (core.recognition.tempering): p(D | l)^β with β fitted on the training touches.
    return np.asarray(model.tempering * values, dtype=np.float64)


def shared_variance(model: ManifoldModel, shared_placement: bool = True) -> FloatArray:
    """The variance of the offset all of a trial's touches share, per model-space feature: the
    drift's σ_d² (:mod:`core.gp.drift_effect`), plus the placement's σ_b² when the touches met one
    placement — each object's own σ_b,l² (:mod:`core.gp.object_placement`) when the model has
    them, one row per object. Zeros for a model with neither. Shape (dy,), or (L, dy) with each
    object's own."""
    variance = np.zeros(model.hyperparameters.observation_dim)
    if shared_placement and model.object_placement_variance is not None:
        variance = variance + model.object_placement_variance
    elif shared_placement and model.placement_variance is not None:
        variance = variance + model.placement_variance
    if model.drift_variance is not None:
        variance = variance + model.drift_variance
    return variance


def _untempered_log_likelihoods(
    model: ManifoldModel,
    actions: FloatArray,
    observations: FloatArray,
    trial_likelihood: TrialLikelihood,
    shared_placement: bool,
) -> FloatArray:
    check_trial_likelihood(trial_likelihood)
    x, y = _check_touches(model, actions, observations)
    n_objects = model.latents.shape[0]
    if x.shape[0] == 0:
        return np.zeros(n_objects)
    variance = shared_variance(model, shared_placement)
    if model.latent_covariance is not None:
        # docs/method.md (L3): every s_l integrated over its Laplace posterior.
        if trial_likelihood == "joint":
            return latent_trial_log_likelihoods(
                model,
                x,
                y,
                variance,
                model.latent_covariance,
                model.shift_variance,
                shared_placement,
                model.shift_creep_variance,
            )
        zero = np.zeros(model.hyperparameters.observation_dim)
        return np.asarray(
            sum(
                latent_trial_log_likelihoods(
                    model, x[t : t + 1], y[t : t + 1], zero, model.latent_covariance
                )
                for t in range(x.shape[0])
            ),
            dtype=np.float64,
        )
    if trial_likelihood == "joint":
        return trial_log_likelihoods(
            model,
            x,
            y,
            variance,
            model.shift_variance,
            shared_placement,
            model.shift_creep_variance,
        )
    # Queries ordered (touch, object): every touch under every learned latent.
    latents = np.tile(model.latents, (x.shape[0], 1))
    queries = np.repeat(x, n_objects, axis=0)
    per_touch = _log_densities(model, latents, queries, np.repeat(y, n_objects, axis=0))
    return np.asarray(per_touch.reshape(x.shape[0], n_objects).sum(axis=0), dtype=np.float64)


def check_trial_likelihood(trial_likelihood: str) -> None:
    """Raise :class:`InvalidInputError` unless ``trial_likelihood`` is one of TRIAL_LIKELIHOODS."""
    if trial_likelihood not in TRIAL_LIKELIHOODS:
        raise InvalidInputError(
            f"trial_likelihood: expected one of {list(TRIAL_LIKELIHOODS)}, received "
            f"{trial_likelihood!r}."
        )


def touch_log_likelihoods(
    model: ManifoldModel, object_index: IntArray, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """log p(y_t | s_{l_t}, x_t) of every touch under its own (known) object, in raw units.

    The held-out predictive log-density used to compare models (noise models, latent
    dimensions): touch t is scored under the learned latent of object ``object_index[t]``, with
    the per-touch density of :func:`object_log_likelihoods` with ``"independent"`` (Jacobian
    included).

    Args:
        model: A conditioned model.
        object_index: Object of every touch, in 0..L-1. Shape (t,).
        actions: Actions. Shape (t, dx).
        observations: Raw observations. Shape (t, dy).

    Returns:
        Log-density of each touch. Shape (t,).
    """
    x, y = _check_touches(model, actions, observations)
    index = np.asarray(object_index)
    n_objects = model.latents.shape[0]
    if index.shape != (x.shape[0],) or not np.issubdtype(index.dtype, np.integer):
        raise InvalidInputError(
            f"object_index: expected {x.shape[0]} integers, received dtype {index.dtype} with "
            f"shape {index.shape}."
        )
    if x.shape[0] and (index.min() < 0 or index.max() >= n_objects):
        raise InvalidInputError(
            f"object_index: values must lie in 0..{n_objects - 1}, received {index.min()}.."
            f"{index.max()}."
        )
    if x.shape[0] == 0:
        return np.zeros(0)
    return _log_densities(model, model.latents[index], x, y)


def _check_touches(
    model: ManifoldModel, actions: FloatArray, observations: FloatArray
) -> tuple[FloatArray, FloatArray]:
    h = model.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    y = as_float_array(observations, "observations", (x.shape[0], h.observation_dim))
    return x, y


def _log_densities(
    model: ManifoldModel, latents: FloatArray, actions: FloatArray, raw: FloatArray
) -> FloatArray:
    """Σ_a log N(y'_a; m_a, v_a) + log|det M| per query row. Shape (Q,)."""
    mean, variance = predict_model_space(model, latents, actions)
    residual = model.to_model_space(raw) - mean
    log_density = -0.5 * (np.log(2.0 * np.pi * variance) + residual**2 / variance)
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    return np.asarray(log_density.sum(axis=1) + jacobian, dtype=np.float64)


def normalise_log_probabilities(log_weights: FloatArray) -> FloatArray:
    """Probabilities from unnormalised log-weights: exp(w - max w), divided by its sum.

    Not exp(w - logsumexp(w)): at |w| ~ 10⁷ (a trial whose touches lie far outside every
    object's predictive) logsumexp is only exact to its last bit, ~2·10⁻⁹, and the
    probabilities would no longer sum to 1. Shape (L,).
    """
    log_weights = np.asarray(log_weights, dtype=np.float64)
    if not np.all(np.isfinite(log_weights)):
        raise InvalidInputError(f"log_weights: must be finite, received {log_weights}.")
    weights = np.exp(log_weights - log_weights.max())
    return np.asarray(weights / weights.sum(), dtype=np.float64)


def object_posterior(
    model: ManifoldModel,
    actions: FloatArray,
    observations: FloatArray,
    trial_likelihood: TrialLikelihood = "joint",
    shared_placement: bool = True,
) -> FloatArray:
    """Posterior probability of each learned object given the touches so far (one trial).

    With a uniform prior over the L objects, p(l | D_t) ∝ p(D_t | l) of
    :func:`object_log_likelihoods` (by default the trial's joint Gaussian). With
    ``trial_likelihood="independent"``,

        p(l | D_t) ∝ Π_t Π_a N(y'_ta; m_a(s_l, x_t), v_a(s_l, x_t) + σ_n,a²),

    where y' = M (y - c) is the observation in the model's space (its observation transform;
    raw y without one), m_a(s_l, x_t) and v_a(s_l, x_t) are the GP predictive mean and variance
    of feature a at the learned latent s_l of object l and the action x_t
    (:func:`core.gp.posterior.predict_model_space`), and σ_n,a² is the feature's noise variance.
    In raw units this is a Gaussian with the full covariance M⁻¹ diag(v + σ_n²) M⁻ᵀ.
    It is computed in log space and normalised with log-sum-exp. With no touches it is uniform.

    Args:
        model: A conditioned model.
        actions: Actions of the touches so far. Shape (t, dx), t ≥ 0.
        observations: Their raw observations. Shape (t, dy).
        trial_likelihood: ``"joint"`` (default) or ``"independent"``.
        shared_placement: Whether the touches met one placement (:func:`object_log_likelihoods`).

    Returns:
        Probabilities summing to 1, in the model's object order. Shape (L,).

    Raises:
        InvalidInputError: Wrong shapes or non-finite values.
    """
    return normalise_log_probabilities(
        object_log_likelihoods(model, actions, observations, trial_likelihood, shared_placement)
    )
