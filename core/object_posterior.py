"""The discrete posterior over the L learned objects given the touches so far.

Kept alongside the Gaussian belief of METHOD.md (M5): the Gaussian is a local, moment-matched
approximation that can settle near the wrong object; this posterior uses the exact GP predictive
likelihood of every touch under every learned object and does not (METHOD.md, "A known failure
mode" and "Recommended defaults: Decision").

A model with a placement effect (``model.placement_variance`` with a value > 0, estimated from a
collection that recorded placements: :mod:`core.placement_effect`) scores the touches of a trial
as one joint Gaussian per object instead of a product of independent touches
(docs/calibration.md). Every caller — the recognition session's answer, stop rule and the
discriminative policy's probabilities — goes through :func:`object_log_likelihoods`.
"""

from __future__ import annotations

import numpy as np
import scipy.special

from core.errors import InvalidInputError
from core.placement_effect import trial_log_likelihoods
from core.posterior import predict_model_space
from core.types import ManifoldModel
from core.validation import FloatArray, IntArray, as_float_array


def object_log_likelihoods(
    model: ManifoldModel, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """log p(D_t | l) of one trial's touches D_t under every learned object l.

    Without a placement effect (``model.placement_variance`` ``None`` or zero), the touches are
    independent given the object:

        log p(D_t | l) = Σ_t [Σ_a log N(y'_ta; m_a(s_l, x_t), v_a(s_l, x_t) + σ_n,a²) + log|det M|].

    The observations come in raw units and are mapped to the model space y' = M (y - c) of the
    model's observation transform (the identity for a model without one); m_a and v_a are the
    GP predictive mean and variance of f_a at the learned latent s_l and action x_t
    (:func:`core.posterior.predict_model_space`, which adds the noise variance). The features of
    y' are independent given (s, x); the Jacobian log|det M| (= -½ log det Σ_ε, METHOD.md "Real
    tactile data") makes the value a log-density of the raw observations.

    With a placement effect the touches are the ones of one placement (a trial) and share its
    offset: the value is the joint Gaussian of :func:`core.placement_effect.trial_log_likelihoods`
    (equal to the above for one touch; it is not a sum over touches, so pass all of a trial's
    touches at once).

    Args:
        model: A conditioned model.
        actions: Actions x_t of the touches. Shape (t, dx).
        observations: Raw observations y_t. Shape (t, dy).

    Returns:
        Log-likelihood of the touches under each object. Shape (L,).
    """
    x, y = _check_touches(model, actions, observations)
    n_objects = model.latents.shape[0]
    if x.shape[0] == 0:
        return np.zeros(n_objects)
    if has_placement_effect(model):
        assert model.placement_variance is not None  # has_placement_effect checked it
        return trial_log_likelihoods(model, x, y, model.placement_variance)
    # Queries ordered (touch, object): every touch under every learned latent.
    latents = np.tile(model.latents, (x.shape[0], 1))
    queries = np.repeat(x, n_objects, axis=0)
    per_touch = _log_densities(model, latents, queries, np.repeat(y, n_objects, axis=0))
    return np.asarray(per_touch.reshape(x.shape[0], n_objects).sum(axis=0), dtype=np.float64)


def has_placement_effect(model: ManifoldModel) -> bool:
    """Whether the model scores a trial's touches jointly (a placement variance > 0)."""
    variance = model.placement_variance
    return variance is not None and bool(np.any(np.asarray(variance) > 0))


def touch_log_likelihoods(
    model: ManifoldModel, object_index: IntArray, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """log p(y_t | s_{l_t}, x_t) of every touch under its own (known) object, in raw units.

    The held-out predictive log-density used to compare models (noise models, latent
    dimensions): touch t is scored under the learned latent of object ``object_index[t]``, with
    the same density as :func:`object_log_likelihoods` (Jacobian included).

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
    """exp(w - logsumexp(w)): probabilities from unnormalised log-weights. Shape (L,)."""
    log_weights = np.asarray(log_weights, dtype=np.float64)
    if not np.all(np.isfinite(log_weights)):
        raise InvalidInputError(f"log_weights: must be finite, received {log_weights}.")
    return np.asarray(np.exp(log_weights - scipy.special.logsumexp(log_weights)), dtype=np.float64)


def object_posterior(
    model: ManifoldModel, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """Posterior probability of each learned object given the touches so far (one trial).

    With a uniform prior over the L objects and no placement effect,

        p(l | D_t) ∝ Π_t Π_a N(y'_ta; m_a(s_l, x_t), v_a(s_l, x_t) + σ_n,a²),

    where y' = M (y - c) is the observation in the model's space (its observation transform;
    raw y without one), m_a(s_l, x_t) and v_a(s_l, x_t) are the GP predictive mean and variance
    of feature a at the learned latent s_l of object l and the action x_t
    (:func:`core.posterior.predict_model_space`), and σ_n,a² is the feature's noise variance.
    In raw units this is a Gaussian with the full covariance M⁻¹ diag(v + σ_n²) M⁻ᵀ.
    It is computed in log space and normalised with log-sum-exp. With no touches it is uniform.
    With a placement effect the product over touches is replaced by the trial's joint Gaussian
    (:func:`object_log_likelihoods`).

    Args:
        model: A conditioned model.
        actions: Actions of the touches so far. Shape (t, dx), t ≥ 0.
        observations: Their raw observations. Shape (t, dy).

    Returns:
        Probabilities summing to 1, in the model's object order. Shape (L,).

    Raises:
        InvalidInputError: Wrong shapes or non-finite values.
    """
    return normalise_log_probabilities(object_log_likelihoods(model, actions, observations))
