"""Uncertainty of each object's latent point, carried into the object likelihood.

The object posterior (:mod:`core.recognition.object_posterior`) scores a trial's touches under
object l at its learned latent s_l as if s_l were known exactly. It is a point estimate from the
l-th object's training touches: docs/method.md, "Latent uncertainty in the object likelihood"
(L1)–(L3).

* (L1) **Laplace approximation.** Given the hyperparameters and the other objects' latents, the
  conditional posterior of s_l (flat prior) is approximated by N(s_l*, Σ_l) with
  Σ_l = H_l⁻¹, H_l the ds × ds Hessian of -log p(Y | S, X, γ) (docs/method.md (M2)) with respect
  to s_l at the fitted latents, in closed form (:func:`latent_hessians`; tested against central
  differences of the analytic gradient of (M2) in the tests). Eigenvalues
  of H_l below 1 / ``max_variance`` (a flat or non-convex direction: a latent direction no
  feature resolves) are raised to it: the latent is then no more uncertain than the spread of
  all objects (normalised latents have RMS distance 1 from their centre).
* (L2) **The predictive for object l integrates over s_l**: the touches' joint distribution under
  s_l ~ N(s_l*, Σ_l) is matched by a Gaussian with the exact first two moments, the Gaussian-input
  moments of docs/method.md (M3) extended to several actions at once (cross-covariances between
  the touches and between the features), :func:`trial_moments`.
* (L3) The trial log-likelihood is that Gaussian's log-density (:func:`trial_log_likelihoods`).

With Σ_l → 0 it reduces to today's joint likelihood (docs/calibration.md (C3)).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from core.errors import InvalidInputError
from core.gp.input_shift import shift_covariance
from core.gp.kernels import squared_exponential
from core.gp.linalg import cholesky_with_jitter, gaussian_log_density, inverse_from_cholesky
from core.gp.placement_effect import object_rows
from core.gp.posterior import support_points
from core.recognition.moments import BeliefTerms, action_kernels, belief_terms, object_indicator
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray, as_float_array

#: Largest variance of a latent direction, normalised latent units (the objects' own spread).
MAX_LATENT_VARIANCE = 1.0


@dataclass(frozen=True)
class LatentLaplace:
    """The Laplace approximation of every object's latent point (docs/method.md (L1)).

    Attributes:
        covariance: Σ_l, normalised latent units. Shape (L, ds, ds).
        hessian: H_l, the curvature of -log p with respect to s_l. Shape (L, ds, ds).
        floored: How many eigenvalues of each H_l were raised to 1 / ``max_variance``. Shape (L,).
    """

    covariance: FloatArray
    hessian: FloatArray
    floored: tuple[int, ...]


def latent_hessians(model: ManifoldModel) -> FloatArray:
    """H_l = ∂²(-log p(Y | S, X, γ)) / ∂s_l ∂s_lᵀ at the fitted latents, hyperparameters fixed.

    Analytic (docs/method.md (L1)): per feature, with K the training covariance, M = K⁻¹,
    α = M y and K_d = ∂K/∂s_l,d,

        H_de = (K_d α)ᵀ M (K_e α) − ½ αᵀ K_de α + ½ tr(M K_de) − ½ tr(M K_d M K_e),

    summed over the features. K_d is non-zero only between object l's touches R and the others C
    (within R the latents cancel), K_d = [[0, B_d], [B_dᵀ, 0]], so with M = [[A, G], [Gᵀ, D]]
    the last trace is 2 tr(A B_d D B_eᵀ) + 2 tr(G B_dᵀ G B_eᵀ). One inverse per feature and
    O(ds N³) products in all, where central differences of the gradient took 2 L ds evaluations
    of (M2) (O(L ds N³)). Always the exact dense likelihood of the training touches in the
    model's space, with the fitted noise on the diagonal.

    Args:
        model: A fitted model (its latents at an optimum of (M2)).

    Returns:
        One ds × ds matrix per object. Shape (L, ds, ds).
    """
    h = model.hyperparameters
    data = model.data
    latents = np.array(model.latents, dtype=np.float64)
    n_objects, ds = latents.shape
    touch_latents = latents[data.object_index]
    actions = data.actions - data.actions.mean(axis=0)
    centred = data.observations - data.observation_mean
    rows = [np.flatnonzero(data.object_index == obj) for obj in range(n_objects)]
    others = [np.flatnonzero(data.object_index != obj) for obj in range(n_objects)]
    out = np.zeros((n_objects, ds, ds))
    for a in range(h.observation_dim):
        ls2 = h.latent_lengthscales[a] ** 2
        gram = h.signal_variance[a] * (
            squared_exponential(touch_latents, touch_latents, h.latent_lengthscales[a])
            * squared_exponential(actions, actions, h.action_lengthscales[a])
        )
        cov = gram + h.noise_variance[a] * np.eye(gram.shape[0])
        lower, _ = cholesky_with_jitter(cov, what="training covariance")
        upper_inverse = inverse_from_cholesky(np.asfortranarray(lower.T))  # upper triangle
        inverse = np.triu(upper_inverse) + np.triu(upper_inverse, 1).T
        alpha = inverse @ centred[:, a]
        for obj in range(n_objects):
            r, c = rows[obj], others[obj]
            k_rc = gram[np.ix_(r, c)]
            delta = latents[obj][None, :] - touch_latents[c]  # (|C|, ds)
            # ∂k/∂s_l,d = -k Δ_d / ℓ_d², on the R × C block.
            slopes = [-k_rc * (delta[:, d] / ls2[d])[None, :] for d in range(ds)]
            m_rr, m_rc = inverse[np.ix_(r, r)], inverse[np.ix_(r, c)]
            m_cc = inverse[np.ix_(c, c)]
            # K_d α and the products the trace needs, once per dimension.
            k_alpha = []
            for b in slopes:
                v = np.zeros_like(alpha)
                v[r] = b @ alpha[c]
                v[c] = b.T @ alpha[r]
                k_alpha.append(v)
            a_b = [m_rr @ b for b in slopes]
            d_bt = [m_cc @ b.T for b in slopes]
            g_bt = [m_rc @ b.T for b in slopes]
            for d in range(ds):
                for e in range(d, ds):
                    # ∂²k/∂s_l,d ∂s_l,e = k (Δ_d Δ_e / (ℓ_d² ℓ_e²) − δ_de / ℓ_d²).
                    curvature = (delta[:, d] * delta[:, e]) / (ls2[d] * ls2[e])
                    if d == e:
                        curvature = curvature - 1.0 / ls2[d]
                    k_de = k_rc * curvature[None, :]
                    value = (
                        k_alpha[d] @ inverse @ k_alpha[e]
                        - alpha[r] @ k_de @ alpha[c]
                        + np.sum(m_rc * k_de)
                        - np.sum(a_b[d] * d_bt[e].T)
                        - np.trace(g_bt[d] @ g_bt[e])
                    )
                    out[obj, d, e] += value
                    if e != d:
                        out[obj, e, d] += value
    return out


def laplace_latents(
    model: ManifoldModel, max_variance: float = MAX_LATENT_VARIANCE
) -> LatentLaplace:
    """Σ_l = H_l⁻¹, H_l's eigenvalues kept at or above 1 / ``max_variance`` (docs/method.md (L1)).

    Args:
        model: A fitted model.
        max_variance: Largest variance along any latent direction, normalised units.

    Raises:
        InvalidInputError: ``max_variance`` not finite and > 0.
    """
    if not np.isfinite(max_variance) or max_variance <= 0:
        raise InvalidInputError(f"max_variance: must be finite and > 0, received {max_variance}.")
    hessian = latent_hessians(model)
    covariance = np.empty_like(hessian)
    floored = []
    for obj, block in enumerate(hessian):
        values, vectors = np.linalg.eigh(block)
        kept = np.maximum(values, 1.0 / max_variance)
        floored.append(int(np.sum(values < 1.0 / max_variance)))
        cov = (vectors / kept) @ vectors.T
        covariance[obj] = 0.5 * (cov + cov.T)
    return LatentLaplace(covariance=covariance, hessian=hessian, floored=tuple(floored))


def check_latent_covariance(model: ManifoldModel, covariance: FloatArray) -> FloatArray:
    """Σ_l as a checked array: L symmetric positive definite ds × ds matrices.

    Raises:
        InvalidInputError: Wrong shape, non-finite, not symmetric or not positive definite.
    """
    n_objects, ds = model.latents.shape
    value = as_float_array(covariance, "latent_covariance", (n_objects, ds, ds))
    if not np.allclose(value, np.swapaxes(value, 1, 2), rtol=1e-8, atol=1e-12):
        raise InvalidInputError("latent_covariance: every Σ_l must be symmetric.")
    smallest = np.linalg.eigvalsh(value).min(axis=1)
    if np.any(smallest <= 0):
        bad = int(np.flatnonzero(smallest <= 0)[0])
        raise InvalidInputError(
            f"latent_covariance: every Σ_l must be positive definite; object {bad} has smallest "
            f"eigenvalue {smallest[bad]:.3g}."
        )
    return value


def with_latent_uncertainty(model: ManifoldModel) -> tuple[ManifoldModel, LatentLaplace]:
    """The model with ``latent_covariance`` set to the Laplace Σ_l of :func:`laplace_latents`."""
    laplace = laplace_latents(model)
    return dataclasses.replace(model, latent_covariance=laplace.covariance), laplace


def trial_moments(
    model: ManifoldModel, latent: FloatArray, covariance: FloatArray, actions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Mean and covariance of f(s, x_1..x_T) over every feature for s ~ N(latent, covariance).

    docs/method.md (L2): with the action statistics of (M3) (u_a(x)[l], the belief terms c_a and
    G_ab of the belief N(latent, covariance)) and the cross-action traces
    T_a(x_t, x_t')[l, l'] = Σ_{i∈l, j∈l'} (K_a⁻¹)_ij e_ai(x_t) e_aj(x_t'),

        E[f_a(x_t)] = ȳ_a + c_aᵀ u_a(x_t)
        Cov[f_a(x_t), f_b(x_t')] = u_a(x_t)ᵀ G_ab u_b(x_t') − (c_aᵀ u_a(x_t)) (c_bᵀ u_b(x_t'))
            + δ_ab (σ_f,a² k^x_a(x_t, x_t') − Σ_ll' G_aa[l, l'] T_a(x_t, x_t')[l, l']).

    The noise is not included. As the covariance → 0 the mean is the GP predictive mean at
    (latent, x_t), the features are uncorrelated and each block is the GP's full T × T
    covariance V_a (:func:`core.gp.placement_effect.predictive_covariance`).

    Args:
        model: A conditioned model (dense, sparse or Kronecker with a materialisable K⁻¹).
        latent: Mean of s. Shape (ds,).
        covariance: Covariance of s. Shape (ds, ds).
        actions: x_1..x_T. Shape (T, dx).

    Returns:
        Mean in model space, shape (T, dy); covariance ordered feature-major (index a·T + t),
        shape (dy·T, dy·T).
    """
    h = model.hyperparameters
    ds = h.latent_dim
    s = as_float_array(latent, "latent", (ds,))
    cov_s = as_float_array(covariance, "covariance", (ds, ds))
    x = as_float_array(actions, "actions", (None, h.action_dim))
    return trial_moments_from_terms(model, s, cov_s, x, *trial_action_terms(model, x))


def trial_moments_from_terms(
    model: ManifoldModel,
    latent: FloatArray,
    covariance: FloatArray,
    x: FloatArray,
    responses: FloatArray,
    kernels: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """:func:`trial_moments` from precomputed action terms (:func:`trial_action_terms`)."""
    terms = belief_terms(model, GaussianBelief(mean=latent, cov=covariance))
    return trial_moments_given(model, terms, x, responses, kernels)


def trial_moments_given(
    model: ManifoldModel,
    terms: BeliefTerms,
    x: FloatArray,
    responses: FloatArray,
    kernels: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """:func:`trial_moments` from the belief's terms (:func:`core.recognition.moments.belief_terms`,
    which depend on the belief only, so one belief's serve every trial) and the action terms.

    The trace term is Σ_ll' G_aa[l, l'] T_a(x_t, x_t')[l, l'] = e_a(x_t)ᵀ (K_a⁻¹ ∘ G_aa[obj, obj])
    e_a(x_t'), G_aa expanded to the support points' objects: O(N²) per feature, whatever L.
    """
    h = model.hyperparameters
    dy, t = h.observation_dim, x.shape[0]
    centred = np.einsum("al,atl->ta", terms.weights, responses)  # c_aᵀ u_a(x_t)
    # u_a(x_t)ᵀ G_ab u_b(x_t') for every (a, b, t, t'), then ordered (a, t, b, t')
    pairs = np.matmul(np.matmul(responses[:, None], terms.pair_weights), responses.swapaxes(1, 2))
    cov = np.ascontiguousarray(pairs.transpose(0, 2, 1, 3))
    cov -= centred.T[:, :, None, None] * centred.T[None, None, :, :]
    objects, _ = support_points(model)
    gram_inverse = model.posterior.gram_inverse  # (dy, N, N)
    for a in range(dy):
        prior = h.signal_variance[a] * squared_exponential(x, x, h.action_lengthscales[a])
        weighted = gram_inverse[a] * terms.pair_weights[a, a][np.ix_(objects, objects)]
        trace = kernels[a] @ weighted @ kernels[a].T
        cov[a, :, a, :] += prior - trace
    flat = cov.reshape(dy * t, dy * t)
    return centred + model.data.observation_mean, 0.5 * (flat + flat.T)


def trial_noise(noise_variance: FloatArray, shared_variance: FloatArray, steps: int) -> FloatArray:
    """The noise of T touches, feature-major: per feature σ_s,a² 11ᵀ + (σ_n,a² − σ_s,a²) I, σ_s²
    the part of each touch's noise variance the touches share (docs/calibration.md (C3)).

    Args:
        noise_variance: σ_n,a², each touch's whole noise variance. Shape (dy,).
        shared_variance: σ_s,a² ≤ σ_n,a². Shape (dy,).
        steps: T.

    Returns:
        Shape (dy·T, dy·T).
    """
    noise = np.kron(np.diag(noise_variance - shared_variance), np.eye(steps))
    noise += np.kron(np.diag(shared_variance), np.ones((steps, steps)))
    return np.asarray(noise, dtype=np.float64)


def trial_action_terms(model: ManifoldModel, actions: FloatArray) -> tuple[FloatArray, FloatArray]:
    """u_a(x_t)[l] (dy, T, L) and the action kernels e_ai(x_t) (dy, T, N)."""
    kernels = action_kernels(model, actions)  # (dy, T, N)
    indicator = object_indicator(model)  # (N, L)
    beta = model.posterior.beta  # (dy, N)
    responses = np.einsum("atn,an,nl->atl", kernels, beta, indicator)
    return responses, kernels


def trial_log_likelihoods(
    model: ManifoldModel,
    actions: FloatArray,
    observations: FloatArray,
    placement_variance: FloatArray,
    latent_covariance: FloatArray,
    shift_variance: FloatArray | None = None,
    shared_placement: bool = True,
    shift_creep: FloatArray | None = None,
) -> FloatArray:
    """log p(y_1..y_T | l) of one trial's touches with s_l ~ N(s_l*, Σ_l) (docs/method.md (L3)).

    Under object l the model-space observations y' (feature-major, dy·T) are Gaussian with the
    mean and covariance of :func:`trial_moments` at (s_l*, Σ_l), plus per feature
    σ_b,a² 11ᵀ + (σ_n,a² − σ_b,a²) I (docs/calibration.md (C3)); plus T · log|det M|. With every
    Σ_l = 0 this equals :func:`core.gp.placement_effect.trial_log_likelihoods`.

    Args:
        model: A conditioned model.
        actions: The trial's actions. Shape (T, dx).
        observations: Their raw observations. Shape (T, dy).
        placement_variance: σ_b,a², model space (zeros for none). Shape (dy,), or (L, dy):
            each object's own (:mod:`core.gp.object_placement`), row l under object l.
        latent_covariance: Σ_l. Shape (L, ds, ds).
        shift_variance: σ_δ², a placement's shift of the action (:mod:`core.gp.input_shift`),
            its covariance taken at s_l*. ``None``: none. Shape (dx,).
        shared_placement: Whether the touches met one placement (the shift is then shared).
        shift_creep: σ_c², the shift's variance gained per touch of the placement (``None``:
            none). Shape (dx,).

    Returns:
        Log-likelihood of the trial under each object. Shape (L,).
    """
    h = model.hyperparameters
    x = as_float_array(actions, "actions", (None, h.action_dim))
    y = as_float_array(observations, "observations", (x.shape[0], h.observation_dim))
    rows = object_rows(model, placement_variance)
    covariances = check_latent_covariance(model, latent_covariance)
    n_objects, t = model.latents.shape[0], x.shape[0]
    if t == 0:
        return np.zeros(n_objects)
    target = model.to_model_space(y).T.reshape(-1)  # feature-major
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    action_terms = trial_action_terms(model, x)
    out = np.empty(n_objects)
    for obj in range(n_objects):
        mean, cov = trial_moments_from_terms(
            model, model.latents[obj], covariances[obj], x, *action_terms
        )
        if shift_variance is not None:
            cov = cov + shift_covariance(
                model, model.latents[obj], x, shift_variance, shared_placement, shift_creep
            )
        residual = target - mean.T.reshape(-1)
        noise = trial_noise(h.noise_variance, rows[obj], t)
        out[obj] = gaussian_log_density(residual, cov + noise, "trial covariance")
        out[obj] += t * jacobian
    return out
