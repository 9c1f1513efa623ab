"""The log-likelihood and its gradient by the textbook dense formulas, as a reference.

For every feature a: build the full N × N Gram matrix K_a over the inputs z_i = [s_obj(i); x_i]
(docs/method.md (M1)), invert it with :func:`numpy.linalg.inv`, and take every partial
derivative as ½ tr(W_a ∂K_a/∂θ) with W_a = K_a⁻¹ - β_a β_aᵀ, building one N × N matrix ∂K_a/∂θ per
parameter θ (σ_f², σ_n², each length-scale and every latent coordinate s_kd). No use of the
per-object structure or of the Cholesky factor: O(dy · P · N²) on top of the O(N³) inverse,
P = 2 + ds + dx + L·ds parameters per feature.
"""

from __future__ import annotations

import numpy as np

from core.gp.parameters import ParameterLayout
from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray


def direct_value_and_gradient(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> tuple[float, FloatArray]:
    """-log p(Y | S, X, γ) and its gradient in the packed layout of :mod:`core.gp.parameters`.

    Returns:
        The value and the gradient with respect to (S, log σ_f², log σ_n², log ℓ^s, log ℓ^x).
    """
    h = hyperparameters
    n, dy = data.n_touches, h.observation_dim
    ds, dx, n_objects = h.latent_dim, h.action_dim, data.n_objects
    layout = ParameterLayout.for_data(data, ds)
    obj = data.object_index
    inputs = np.hstack([latents[obj], data.actions])  # z_i, (N, ds + dx)
    sq_diff = [(inputs[:, None, d] - inputs[None, :, d]) ** 2 for d in range(ds + dx)]
    signed = [latents[obj][:, None, d] - latents[obj][None, :, d] for d in range(ds)]
    membership = [(obj == k).astype(np.float64) for k in range(n_objects)]
    centred = data.observations - data.observation_mean
    total = 0.0
    g_latents = np.zeros((n_objects, ds))
    g_sf, g_sn = np.empty(dy), np.empty(dy)
    g_ls, g_lx = np.empty((dy, ds)), np.empty((dy, dx))
    for a in range(dy):
        scales = np.concatenate([h.latent_lengthscales[a], h.action_lengthscales[a]])
        exponent = sum(sq_diff[d] / scales[d] ** 2 for d in range(ds + dx))
        k_free = h.signal_variance[a] * np.exp(-0.5 * exponent)
        gram = k_free + h.noise_variance[a] * np.eye(n)
        inverse = np.linalg.inv(gram)
        y = centred[:, a]
        beta = inverse @ y
        _, log_det = np.linalg.slogdet(gram)
        total += 0.5 * float(y @ beta) + 0.5 * log_det + 0.5 * n * np.log(2.0 * np.pi)
        w = inverse - np.outer(beta, beta)
        g_sf[a] = 0.5 * np.sum(w * k_free)  # ∂K/∂log σ_f² = K_f
        g_sn[a] = 0.5 * h.noise_variance[a] * np.trace(w)  # ∂K/∂log σ_n² = σ_n² I
        for d in range(ds + dx):
            d_gram = k_free * sq_diff[d] / scales[d] ** 2  # ∂K/∂log ℓ_d
            value = 0.5 * np.sum(w * d_gram)
            if d < ds:
                g_ls[a, d] = value
            else:
                g_lx[a, d - ds] = value
        for k in range(n_objects):
            indicator = membership[k][:, None] - membership[k][None, :]
            for d in range(ds):
                # ∂K_ij/∂s_ld = -K_ij (s_oi,d - s_oj,d) / ℓ_d² ([o_i = k] - [o_j = k])
                d_gram = -k_free * signed[d] / scales[d] ** 2 * indicator
                g_latents[k, d] += 0.5 * np.sum(w * d_gram)
    grad = layout.join(g_latents, g_sf, g_sn, g_ls, g_lx)
    return float(total), grad
