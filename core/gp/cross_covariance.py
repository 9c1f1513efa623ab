"""The GP's covariance between touches of one object at two sets of actions, for every object.

Under object l the function values at (s_l, x_t) and (s_l, x'_c) are correlated through the GP
posterior (docs/method.md, "The next touch given the trial's touches"):

    V_a(s_l; x_t, x'_c) = σ_f,a² k^x_a(x_t, x'_c) − q_l,a(x_t)ᵀ A_a q_l,a(x'_c),
    q_l,a(x)_i = σ_f,a² k^s_a(s_l, s_o(i)) k^x_a(x, x_i),

with i over the posterior's support points (the training touches, or the inducing points of a
sparse posterior) and A_a its matrix over them (K_a⁻¹ for dense and Kronecker posteriors). With
X' = X it is :func:`core.gp.placement_effect.predictive_covariance`. A planner needs it between a
trial's T touches and C ≈ 256 candidates for all L objects at every step, so the dense path forms
k^x_a(X', support) once per feature and costs O(dy · L · T · N · (N + C)), not L · C · N² (a K⁻¹
product per candidate and object).
"""

from __future__ import annotations

import numpy as np

from core.gp.kernels import squared_exponential
from core.gp.kronecker import predictive_covariance_kronecker
from core.gp.posterior import support_points
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array

__all__ = ["object_cross_covariances"]


def object_cross_covariances(
    model: ManifoldModel, actions: FloatArray, others: FloatArray
) -> FloatArray:
    """V_a(s_l; x_t, x'_c) for every learned object l and feature a (noise not included).

    Args:
        model: A conditioned model.
        actions: x_1..x_T. Shape (T, dx).
        others: x'_1..x'_C. Shape (C, dx).

    Returns:
        The cross-covariances. Shape (L, dy, T, C).
    """
    h = model.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    x_other = as_float_array(others, "others", (None, h.action_dim))
    n_objects = model.latents.shape[0]
    if model.posterior.kronecker is not None and not model.posterior.has_dense_inverse:
        return np.stack(
            [
                predictive_covariance_kronecker(model, model.latents[obj], x, x_other)
                for obj in range(n_objects)
            ]
        )
    support_objects, support_actions = support_points(model)
    gram_inverse = model.posterior.gram_inverse
    out = np.empty((n_objects, h.observation_dim, x.shape[0], x_other.shape[0]))
    for a in range(h.observation_dim):
        signal = h.signal_variance[a]
        k_latent = squared_exponential(model.latents, model.latents, h.latent_lengthscales[a])
        k_action = squared_exponential(x, support_actions, h.action_lengthscales[a])  # (T, N)
        k_other = squared_exponential(x_other, support_actions, h.action_lengthscales[a])  # (C, N)
        prior = signal * squared_exponential(x, x_other, h.action_lengthscales[a])  # (T, C)
        for obj in range(n_objects):
            weight = signal * k_latent[obj, support_objects]  # (N,)
            projected = ((weight * k_action) @ gram_inverse[a]) * weight  # q(X)ᵀ A, weighted
            out[obj, a] = prior - projected @ k_other.T
    return out
