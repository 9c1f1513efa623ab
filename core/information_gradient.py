"""Analytic gradient of the mutual information U1 with respect to the action x (for refinement).

U1(x) = ½ [log det Σ - log det P],  P = Σ - C S⁻¹ Cᵀ   (METHOD.md eq. (M4))

depends on x only through the action statistics u_a(x) and T_a(x) of METHOD.md's structured
(M3). With W = -½ S⁻¹ Cᵀ P⁻¹ C S⁻¹ (= ∂U1/∂S) and Γ = P⁻¹ C S⁻¹ (= ∂U1/∂C):

    ∂U1/∂u_a[l]      = 2 Σ_b W_ab (G_ab u_b)[l] - 2 (Σ_b W_ab m̃_b) c_a[l] + c_a[l] Γ_{:,a}ᵀ D_a[l]
    ∂U1/∂T_a[l, l']  = -W_aa G_aa[l, l']

with m̃ the centred mean, and the chain rule through ∂e_ai/∂x = -e_ai (Λ^x_a)⁻¹ (x - x_i).
"""

from __future__ import annotations

import numpy as np

from core.moments import (
    ActionStatistics,
    BeliefTerms,
    action_kernels,
    belief_terms,
    moments_from_terms,
    object_indicator,
)
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array


def _statistics_with_derivatives(
    model: ManifoldModel, action: FloatArray, indicator: FloatArray
) -> tuple[ActionStatistics, FloatArray, FloatArray]:
    """u, T of one action and their derivatives du/dx (dy, dx, L), dT/dx (dy, dx, L, L)."""
    kernels, scaled = action_kernels(model, action[None, :])
    e = kernels[:, 0, :]  # (dy, N)
    de = -e[:, :, None] * scaled[:, 0, :, :]  # (dy, N, dx)
    beta = model.posterior.beta
    weighted = beta[:, :, None] * indicator[None]  # (dy, N, L): β_ai [obj_i = l]
    responses = np.einsum("an,anl->al", e, weighted)
    d_responses = np.einsum("and,anl->adl", de, weighted)
    masked = e[:, :, None] * indicator[None]  # (dy, N, L): e_ai [obj_i = l]
    partial = model.posterior.gram_inverse @ masked  # (dy, N, L): Y[i, l'] = Σ_{j∈l'} K⁻¹_ij e_j
    trace_blocks = np.swapaxes(masked, 1, 2) @ partial  # (dy, L, L)
    half = np.einsum("and,anl,anm->adlm", de, indicator[None], partial)
    d_trace = half + np.swapaxes(half, 2, 3)
    stats = ActionStatistics(
        actions=action[None, :], responses=responses[None], trace_blocks=trace_blocks[None]
    )
    return stats, d_responses, d_trace


def mutual_information_and_gradient(
    model: ManifoldModel,
    belief: GaussianBelief,
    action: FloatArray,
    terms: BeliefTerms | None = None,
) -> tuple[float, FloatArray]:
    """U1 at one action and its gradient dU1/dx (METHOD.md eq. (M4)).

    Cost O(dy · N² + dy · dx · N · L) per call (one pass over each K_a⁻¹).

    Args:
        model: A conditioned model.
        belief: s ~ N(μ, Σ).
        action: The action x. Shape (dx,).
        terms: Belief terms of ``belief`` (from :func:`core.moments.belief_terms`), to reuse
            across calls with the same belief; computed when ``None``.

    Returns:
        The mutual information (nats) and its gradient. Shape of the gradient (dx,).
    """
    x = as_float_array(action, "action", (model.hyperparameters.action_dim,))
    if terms is None:
        terms = belief_terms(model, belief)
    indicator = object_indicator(model)
    stats, d_responses, d_trace = _statistics_with_derivatives(model, x, indicator)
    moments = moments_from_terms(model, terms, stats)
    s_cov = moments.cov[0]
    cross = moments.cross_cov[0]  # (ds, dy)
    s_inv_ct = np.linalg.solve(s_cov, cross.T)  # S⁻¹ Cᵀ, (dy, ds)
    post = belief.cov - cross @ s_inv_ct  # P
    post = 0.5 * (post + post.T)
    _, logdet_sigma = np.linalg.slogdet(belief.cov)
    _, logdet_post = np.linalg.slogdet(post)
    value = 0.5 * (logdet_sigma - logdet_post)
    gamma = np.linalg.solve(post, s_inv_ct.T)  # P⁻¹ C S⁻¹, (ds, dy)
    w = -0.5 * s_inv_ct @ gamma  # (dy, dy)
    w = 0.5 * (w + w.T)

    u = stats.responses[0]  # (dy, L)
    c = terms.weights  # (dy, L)
    centred_mean = np.sum(c * u, axis=1)  # (dy,)
    pair_u = np.einsum("ablm,bm->abl", terms.pair_weights, u)
    grad_u = 2.0 * np.einsum("ab,abl->al", w, pair_u)
    grad_u -= 2.0 * (w @ centred_mean)[:, None] * c
    grad_u += c * np.einsum("da,ald->al", gamma, terms.offsets)
    diagonal_pair = np.einsum("aalm->alm", terms.pair_weights)
    grad_t = -np.diagonal(w)[:, None, None] * diagonal_pair  # (dy, L, L)
    gradient = np.einsum("al,adl->d", grad_u, d_responses)
    gradient += np.einsum("alm,adlm->d", grad_t, d_trace)
    return float(value), np.asarray(gradient, dtype=np.float64)
