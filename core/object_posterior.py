"""The discrete posterior over the L learned objects given the touches so far.

Kept alongside the Gaussian belief of METHOD.md (M5): the Gaussian is a local, moment-matched
approximation that can settle near the wrong object; this posterior uses the exact GP predictive
likelihood of every touch under every learned object and does not (METHOD.md, "A known failure
mode" and "Recommended defaults: Decision").
"""

from __future__ import annotations

import numpy as np
import scipy.special

from core.errors import InvalidInputError
from core.posterior import predict
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array


def object_log_likelihoods(
    model: ManifoldModel, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """log p(D_t | l) = Σ_t Σ_a log N(y_ta; m_a(s_l, x_t), v_a(s_l, x_t) + σ_n,a²) for every l.

    m_a and v_a are the GP predictive mean and variance of f_a at the learned latent s_l and
    action x_t (:func:`core.posterior.predict`, which adds the noise variance). The features are
    independent given (s, x), and the touches are treated as independent given the object.

    Args:
        model: A conditioned model.
        actions: Actions x_t of the touches. Shape (t, dx).
        observations: Observations y_t. Shape (t, dy).

    Returns:
        Log-likelihood of the touches under each object. Shape (L,).
    """
    h = model.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    y = as_float_array(observations, "observations", (x.shape[0], h.observation_dim))
    n_objects = model.latents.shape[0]
    if x.shape[0] == 0:
        return np.zeros(n_objects)
    # Queries ordered (touch, object): every touch under every learned latent.
    latents = np.tile(model.latents, (x.shape[0], 1))
    queries = np.repeat(x, n_objects, axis=0)
    mean, variance = predict(model, latents, queries)
    residual = np.repeat(y, n_objects, axis=0) - mean
    log_density = -0.5 * (np.log(2.0 * np.pi * variance) + residual**2 / variance)
    per_touch = log_density.sum(axis=1).reshape(x.shape[0], n_objects)
    return np.asarray(per_touch.sum(axis=0), dtype=np.float64)


def normalise_log_probabilities(log_weights: FloatArray) -> FloatArray:
    """exp(w - logsumexp(w)): probabilities from unnormalised log-weights. Shape (L,)."""
    log_weights = np.asarray(log_weights, dtype=np.float64)
    if not np.all(np.isfinite(log_weights)):
        raise InvalidInputError(f"log_weights: must be finite, received {log_weights}.")
    return np.asarray(np.exp(log_weights - scipy.special.logsumexp(log_weights)), dtype=np.float64)


def object_posterior(
    model: ManifoldModel, actions: FloatArray, observations: FloatArray
) -> FloatArray:
    """Posterior probability of each learned object given the touches so far.

    With a uniform prior over the L objects,

        p(l | D_t) ∝ Π_t Π_a N(y_ta; m_a(s_l, x_t), v_a(s_l, x_t) + σ_n,a²),

    where m_a(s_l, x_t) and v_a(s_l, x_t) are the GP predictive mean and variance of feature a at
    the learned latent s_l of object l and the action x_t (:func:`core.posterior.predict`), and
    σ_n,a² is the feature's noise variance. It is computed in log space and normalised with
    log-sum-exp. With no touches it is uniform.

    Args:
        model: A conditioned model.
        actions: Actions of the touches so far. Shape (t, dx), t ≥ 0.
        observations: Their observations. Shape (t, dy).

    Returns:
        Probabilities summing to 1, in the model's object order. Shape (L,).

    Raises:
        InvalidInputError: Wrong shapes or non-finite values.
    """
    return normalise_log_probabilities(object_log_likelihoods(model, actions, observations))
