"""Analytic gradient of the mutual information U1 with respect to the action x (for refinement).

U1(x) = ½ [log det Σ - log det P],  P = Σ - C S⁻¹ Cᵀ   (docs/method.md eq. (M4))

depends on x only through the action statistics u_a(x) and T_a(x) of docs/method.md's structured
(M3). With W = -½ S⁻¹ Cᵀ P⁻¹ C S⁻¹ (= ∂U1/∂S) and Γ = P⁻¹ C S⁻¹ (= ∂U1/∂C):

    ∂U1/∂u_a[l]      = 2 Σ_b W_ab (G_ab u_b)[l] - 2 (Σ_b W_ab m̃_b) c_a[l] + c_a[l] Γ_{:,a}ᵀ D_a[l]
    ∂U1/∂T_a[l, l']  = -W_aa G_aa[l, l']

with m̃ the centred mean, and the chain rule through ∂e_ai/∂x = -e_ai (Λ^x_a)⁻¹ (x - x_i).

On a Kronecker posterior T_a = U_a diag(t_a) U_aᵀ, so ∂U1/∂t_a[j] = -W_aa (U_aᵀ G_aa U_a)_jj and
the derivatives of u and t come from :func:`core.gp.kronecker.action_statistics_derivatives`
(O(dy · dx · (M² + L·M)) per call instead of O(dy · N²)). On a sparse posterior the sums run
over its inducing points.
"""

from __future__ import annotations

import numpy as np

from core.gp.kronecker import action_statistics_derivatives
from core.gp.posterior import support_points
from core.recognition.moments import (
    ActionStatistics,
    BeliefTerms,
    SupportBlocks,
    action_kernels,
    belief_terms,
    moments_from_terms,
    object_indicator,
)
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array


class GradientCache:
    """Per-model arrays reused by every gradient evaluation (build once per model).

    A Kronecker posterior needs none of them (its statistics come from its factors), so they are
    left empty there.
    """

    def __init__(self, model: ManifoldModel) -> None:
        if model.posterior.kronecker is not None:
            self.blocks = SupportBlocks(np.zeros(0, dtype=np.int64), model.data.n_objects)
            self.indicator = np.zeros((0, model.data.n_objects))
            self.weighted_beta = np.zeros((0, 0, 0))
            self.located_actions = np.zeros((0, 0))
            self.inverse_sq_lengthscales = 1.0 / model.hyperparameters.action_lengthscales**2
            self.actions_t = np.zeros((model.data.action_dim, 0))
            return
        objects, _ = support_points(model)
        self.blocks = SupportBlocks(objects, model.data.n_objects)
        self.indicator = object_indicator(model)  # (N, L)
        # β_ai [obj_i = l], (dy, N, L)
        self.weighted_beta = model.posterior.beta[:, :, None] * self.indicator[None]
        # x_id [obj_i = l], laid out (dx·L, N), over the support points
        _, actions = support_points(model)
        n = actions.shape[0]
        self.located_actions = np.ascontiguousarray(
            (actions[:, :, None] * self.indicator[:, None, :]).reshape(n, -1).T
        )
        self.inverse_sq_lengthscales = 1.0 / model.hyperparameters.action_lengthscales**2
        self.actions_t = np.ascontiguousarray(actions.T)  # (dx, N)


def _statistics_with_derivatives(
    model: ManifoldModel, action: FloatArray, cache: GradientCache
) -> tuple[ActionStatistics, FloatArray, FloatArray]:
    """u, T of one action and their derivatives du/dx (dy, dx, L), dT/dx (dy, dx, L, L); on a
    Kronecker posterior the trace spectrum t (dy, L) and dt/dx (dy, dx, L) instead."""
    factors = model.posterior.kronecker
    if factors is not None:
        responses, d_responses, spectrum, d_spectrum = action_statistics_derivatives(model, action)
        stats = ActionStatistics(
            actions=action[None, :],
            responses=responses[None],
            trace_blocks=spectrum[None],
            trace_basis=factors.latent_eigenvectors,
        )
        return stats, d_responses, d_spectrum
    e = action_kernels(model, action[None, :])[:, 0, :]  # (dy, N)
    diff_t = (action[:, None] - cache.actions_t)[None]  # (1, dx, N): x_d - x_id
    # ∂e_ai/∂x_d = -e_ai (x_d - x_id) / ℓ_ad², (dy, dx, N)
    de_t = -diff_t * cache.inverse_sq_lengthscales[:, :, None] * e[:, None, :]
    if cache.blocks.reduce:
        return _block_statistics_with_derivatives(model, action, cache, e, de_t)
    responses = (e[:, None, :] @ cache.weighted_beta)[:, 0, :]  # (dy, L)
    d_responses = de_t @ cache.weighted_beta  # (dy, dx, L)
    indicator = cache.indicator
    masked = e[:, :, None] * indicator[None]  # (dy, N, L): e_ai [obj_i = l]
    partial = model.posterior.gram_inverse @ masked  # (dy, N, L): Y[i, l'] = Σ_{j∈l'} K⁻¹_ij e_j
    trace_blocks = np.swapaxes(masked, 1, 2) @ partial  # (dy, L, L)
    # half[a, d, l, l'] = Σ_{i∈l} ∂e_ai/∂x_d Y[i, l']
    #                   = -(1/ℓ_ad²) (x_d T_a[l, l'] - Σ_{i∈l} x_id e_ai Y[i, l'])
    # and dT = half + halfᵀ.
    dy, dx = de_t.shape[:2]
    n_objects = indicator.shape[1]
    located = cache.located_actions @ (e[:, :, None] * partial)  # (dy, dx·L, L)
    located = located.reshape(dy, dx, n_objects, n_objects)
    return _finish(action, responses, d_responses, trace_blocks, located, cache)


def _block_statistics_with_derivatives(
    model: ManifoldModel, action: FloatArray, cache: GradientCache, e: FloatArray, de_t: FloatArray
) -> tuple[ActionStatistics, FloatArray, FloatArray]:
    """The same as the dense path for many objects with grouped support points: per-object
    sums instead of products with the one-hot indicator (O(dy · (N² + dx · N · L)) instead of
    O(dy · L · (N² + dx · N · L)))."""
    blocks = cache.blocks
    beta = model.posterior.beta
    gram_inverse = model.posterior.gram_inverse
    responses = blocks.sums(e * beta)  # (dy, L)
    d_responses = blocks.sums(de_t * beta[:, None, :])  # (dy, dx, L)
    # Yᵀ[l', i] = Σ_{j∈l'} K⁻¹_ji e_j  (K⁻¹ is symmetric)
    partial_t = blocks.sums(e[:, :, None] * gram_inverse, axis=1)  # (dy, L', N)
    weighted = np.moveaxis(partial_t * e[:, None, :], 2, 0)  # e_i Y[i, l'], (N, dy, L')
    trace_blocks = np.moveaxis(blocks.sums(weighted, axis=0), 0, 1)  # (dy, L, L')
    # Σ_{i∈l} x_id e_ai Y[i, l'], one small GEMM per object block
    n_objects = blocks.n_objects
    flat = weighted.reshape(weighted.shape[0], -1)  # (N, dy·L')
    actions = cache.actions_t.T  # (N, dx)
    located_l = np.zeros((n_objects, flat.shape[1], actions.shape[1]))  # (L, dy·L', dx)
    for obj in blocks.present:
        block = blocks.members[obj]
        assert block is not None
        located_l[obj] = flat[block].T @ actions[block]
    dy = weighted.shape[1]
    located = np.moveaxis(located_l.reshape(n_objects, dy, n_objects, -1), (0, 3), (2, 1))
    return _finish(action, responses, d_responses, trace_blocks, located, cache)


def _finish(
    action: FloatArray,
    responses: FloatArray,
    d_responses: FloatArray,
    trace_blocks: FloatArray,
    located: FloatArray,
    cache: GradientCache,
) -> tuple[ActionStatistics, FloatArray, FloatArray]:
    """The statistics at one action and dT = half + halfᵀ, where half is
    -(x ⊗ T - Σ x_i e_i Y) / ℓ^x² per feature (both statistics paths end here).

    Args:
        action: x. Shape (dx,).
        responses: Shape (dy, L).
        d_responses: Shape (dy, dx, L).
        trace_blocks: T. Shape (dy, L, L).
        located: Σ_{i∈l} x_id e_ai Y[i, l']. Shape (dy, dx, L, L).
        cache: The model's gradient cache.
    """
    half = action[None, :, None, None] * trace_blocks[:, None, :, :] - located
    half *= -cache.inverse_sq_lengthscales[:, :, None, None]
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
    cache: GradientCache | None = None,
) -> tuple[float, FloatArray]:
    """U1 at one action and its gradient dU1/dx (docs/method.md eq. (M4)).

    Cost O(dy · N² + dy · dx · N · L) per call (one pass over each K_a⁻¹).

    Args:
        model: A conditioned model.
        belief: s ~ N(μ, Σ).
        action: The action x. Shape (dx,).
        terms: Belief terms of ``belief`` (from :func:`core.recognition.moments.belief_terms`), to
        reuse
            across calls with the same belief; computed when ``None``.
        cache: Per-model arrays (:class:`GradientCache`) to reuse across calls; built when
            ``None``.

    Returns:
        The mutual information (nats) and its gradient. Shape of the gradient (dx,).
    """
    x = as_float_array(action, "action", (model.hyperparameters.action_dim,))
    if terms is None:
        terms = belief_terms(model, belief)
    if cache is None:
        cache = GradientCache(model)
    stats, d_responses, d_trace = _statistics_with_derivatives(model, x, cache)
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
    gradient = np.einsum("al,adl->d", grad_u, d_responses)
    if stats.trace_basis is not None:
        spectral = terms.spectral_weights
        if spectral is None:
            spectral = np.sum(
                stats.trace_basis
                * (np.einsum("aalm->alm", terms.pair_weights) @ stats.trace_basis),
                axis=1,
            )
        grad_spectrum = -np.diagonal(w)[:, None] * spectral  # ∂U1/∂t_a, (dy, L)
        gradient += np.einsum("aj,adj->d", grad_spectrum, d_trace)
    else:
        diagonal_pair = np.einsum("aalm->alm", terms.pair_weights)
        grad_t = -np.diagonal(w)[:, None, None] * diagonal_pair  # (dy, L, L)
        gradient += np.einsum("alm,adlm->d", grad_t, d_trace)
    return float(value), np.asarray(gradient, dtype=np.float64)
