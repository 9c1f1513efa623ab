"""Condition the per-feature GPs on the training touches (METHOD.md eq. (M1)–(M2))."""

from __future__ import annotations

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.kernels import squared_exponential
from core.linalg import cholesky_with_jitter, log_det_from_cholesky
from core.types import (
    FitDiagnostics,
    GPPosterior,
    Hyperparameters,
    ManifoldModel,
    TrainingData,
)
from core.validation import FloatArray, as_float_array


def gram_matrix(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters, feature: int
) -> FloatArray:
    """Noisy Gram matrix K_a = σ_f² K^s[obj, obj] ∘ K^x + σ_n² I of one feature (M1).

    Args:
        data: Training touches (N of them).
        latents: Object latents. Shape (L, ds).
        hyperparameters: GP hyperparameters.
        feature: The feature index a.

    Returns:
        K_a. Shape (N, N).
    """
    h = hyperparameters
    latent_gram = squared_exponential(latents, latents, h.latent_lengthscales[feature])
    action_gram = squared_exponential(data.actions, data.actions, h.action_lengthscales[feature])
    obj = data.object_index
    gram = h.signal_variance[feature] * latent_gram[np.ix_(obj, obj)] * action_gram
    gram[np.diag_indices_from(gram)] += h.noise_variance[feature]
    return np.asarray(gram, dtype=np.float64)


def condition(
    data: TrainingData,
    latents: FloatArray,
    hyperparameters: Hyperparameters,
    diagnostics: FitDiagnostics | None = None,
) -> ManifoldModel:
    """Build a :class:`ManifoldModel`: Cholesky of each K_a, β_a, K_a⁻¹ and the log-likelihood.

    Args:
        data: Training touches.
        latents: Object latents s_l. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters (dy features, ds latent, dx action dims).
        diagnostics: Optional fit diagnostics to attach.

    Raises:
        InvalidInputError: Shapes disagree between data, latents and hyperparameters.
        NotPositiveDefiniteError: A Gram matrix is singular even with jitter.
    """
    h = hyperparameters
    latents = as_float_array(latents, "latents", (data.n_objects, h.latent_dim))
    if h.action_dim != data.action_dim or h.observation_dim != data.observation_dim:
        raise InvalidInputError(
            f"hyperparameters are for dx={h.action_dim}, dy={h.observation_dim} but the data "
            f"has dx={data.action_dim}, dy={data.observation_dim}."
        )
    n = data.n_touches
    centred = data.observations - data.observation_mean
    beta = np.empty((h.observation_dim, n))
    gram_inverse = np.empty((h.observation_dim, n, n))
    jitter = np.zeros(h.observation_dim)
    log_likelihood = 0.0
    identity = np.eye(n)
    for a in range(h.observation_dim):
        factor, jitter[a] = cholesky_with_jitter(
            gram_matrix(data, latents, h, a), what=f"Gram matrix of feature {a}"
        )
        beta[a] = scipy.linalg.cho_solve((factor, True), centred[:, a], check_finite=False)
        gram_inverse[a] = scipy.linalg.cho_solve((factor, True), identity, check_finite=False)
        # METHOD.md eq. (M2)
        log_likelihood += (
            -0.5 * float(centred[:, a] @ beta[a])
            - 0.5 * log_det_from_cholesky(factor)
            - 0.5 * n * np.log(2.0 * np.pi)
        )
    latents.flags.writeable = False
    for array in (beta, gram_inverse, jitter):
        array.flags.writeable = False
    return ManifoldModel(
        data=data,
        latents=latents,
        hyperparameters=h,
        posterior=GPPosterior(beta=beta, gram_inverse=gram_inverse, jitter=jitter),
        log_likelihood=float(log_likelihood),
        diagnostics=diagnostics,
    )


def predict(
    model: ManifoldModel, latents: FloatArray, actions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """GP predictive mean and variance of the observation at deterministic inputs (s, x).

    Args:
        model: A conditioned model.
        latents: Query latents. Shape (Q, ds).
        actions: Query actions. Shape (Q, dx).

    Returns:
        Mean (Q, dy) and variance of y including the noise variance (Q, dy).
    """
    h = model.hyperparameters
    latents = as_float_array(latents, "latents", (None, h.latent_dim))
    actions = as_float_array(actions, "actions", (latents.shape[0], h.action_dim))
    data = model.data
    mean = np.empty((latents.shape[0], h.observation_dim))
    variance = np.empty_like(mean)
    for a in range(h.observation_dim):
        k_latent = squared_exponential(latents, model.latents, h.latent_lengthscales[a])
        k_action = squared_exponential(actions, data.actions, h.action_lengthscales[a])
        cross = h.signal_variance[a] * k_latent[:, data.object_index] * k_action
        mean[:, a] = data.observation_mean[a] + cross @ model.posterior.beta[a]
        reduction = np.einsum("qi,ij,qj->q", cross, model.posterior.gram_inverse[a], cross)
        variance[:, a] = np.maximum(h.signal_variance[a] - reduction, 0.0) + h.noise_variance[a]
    return mean, variance
