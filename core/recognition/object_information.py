"""Information about *which object* a touch would give (the ``discriminative`` policy).

The object posterior p_l over the L learned objects (:mod:`core.recognition.object_posterior`)
treats a touch's observation under object l as y | l, x ~ N(m_l(x), V_l(x)): the GP predictive at
the learned latent s_l with a point belief, V_l(x) diagonal (the features are independent given
(s, x)) and including the noise. Before the touch, y is distributed as the mixture
Σ_l p_l N(m_l(x), V_l(x)), and the information it carries about the label is

    I(l; y | x) = H(y | x) − Σ_l p_l H(y | l, x),

where the mixture entropy H(y | x) has no closed form. Two principled estimates:

* :func:`label_information_mc` — Monte Carlo, I = Σ_l p_l E_{y ~ l}[log p(y | l) − log p(y)],
  with common random numbers: the same standard-normal draws ξ_k are mapped through every
  candidate's and every object's predictive, y = m_l + √V_l ∘ ξ_k, so the differences between
  candidates are estimated with far less noise than their values (and the choice of action is
  deterministic for a planner's fixed draws);
* :func:`label_information_bounds` — the pairwise-distance bounds of Kolchinsky & Tracey (2017,
  "Estimating mixture entropy with pairwise distances"): with D a divergence between components,
  Î_D = −Σ_i p_i log Σ_j p_j exp(−D(i ‖ j)) is a lower bound on I for the Bhattacharyya distance
  and an upper bound for the Kullback–Leibler divergence; both are 0 when one object is certain
  and tend to the label entropy H(p) as the components separate.

The predictive moments at a learned latent come from a planner's cached action statistics
(:class:`core.recognition.moments.ActionStatistics`): with a point belief at s_l the moments of (M3)
reduce to m_a = ȳ_a + σ_f,a² k_a(s_l)ᵀ u_a(x) and V_a = σ_f,a² − σ_f,a⁴ k_a(s_l)ᵀ T_a(x) k_a(s_l) +
σ_n,a², k_a(s_l)[l'] = exp(−½ |s_l − s_l'|²_{Λ^s_a}) (:func:`object_predictives`).
"""

from __future__ import annotations

import numpy as np
import scipy.special

from core.errors import InvalidInputError
from core.gp.kernels import squared_exponential
from core.recognition.moments import ActionStatistics
from core.types import ManifoldModel
from core.validation import FloatArray, as_float_array

#: Smallest predictive variance used (guards the log against a variance rounded to 0).
_VARIANCE_FLOOR = 1e-12


def object_predictives(
    model: ManifoldModel, stats: ActionStatistics
) -> tuple[FloatArray, FloatArray]:
    """Predictive mean and variance (with noise) of y at every learned latent and candidate.

    Equal to :func:`core.gp.posterior.predict` at (s_l, x) for every l and candidate x, computed
    from the action statistics in O(C · dy · L²).

    Args:
        model: A conditioned model.
        stats: Action statistics of C candidates for ``model``.

    Returns:
        Mean (C, L, dy) and variance (C, L, dy).

    Raises:
        InvalidInputError: The statistics were computed for another model shape.
    """
    h = model.hyperparameters
    n_objects = model.data.n_objects
    if stats.responses.shape[1:] != (h.observation_dim, n_objects):
        raise InvalidInputError(
            f"stats: computed for (dy, L) = {stats.responses.shape[1:]}, the model has "
            f"(dy, L) = {(h.observation_dim, n_objects)}."
        )
    n_actions = stats.n_actions
    mean = np.empty((n_actions, n_objects, h.observation_dim))
    variance = np.empty_like(mean)
    for a in range(h.observation_dim):
        kernel = squared_exponential(model.latents, model.latents, h.latent_lengthscales[a])
        signal = h.signal_variance[a]
        # m_a(s_l, x) - ȳ_a = σ_f² Σ_l' k(s_l, s_l') u_a(x)[l']
        mean[:, :, a] = model.data.observation_mean[a] + signal * (stats.responses[:, a] @ kernel)
        if stats.trace_basis is None:
            # k_lᵀ T_a(x) k_l for every l: rows of K^s T_a K^s's diagonal.
            blocks = stats.trace_blocks[:, a]  # (C, L, L)
            reduction = np.einsum("lm,cmn,ln->cl", kernel, blocks, kernel)
        else:
            projected = kernel @ stats.trace_basis[a]  # (L, L): row l is (U_aᵀ k_l)ᵀ
            reduction = stats.trace_blocks[:, a] @ (projected**2).T  # Σ_j t_j (U_aᵀ k_l)_j²
        variance[:, :, a] = np.maximum(signal - signal**2 * reduction, 0.0) + h.noise_variance[a]
    return mean, variance


def _check_mixture(
    probabilities: FloatArray, mean: FloatArray, variance: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    mean = as_float_array(mean, "mean", (None, None, None))
    variance = as_float_array(variance, "variance", mean.shape)
    p = as_float_array(probabilities, "probabilities", (mean.shape[1],))
    if np.any(p < 0) or not np.isclose(p.sum(), 1.0, atol=1e-6):
        raise InvalidInputError(
            f"probabilities: must be ≥ 0 and sum to 1, received sum {p.sum()} and min {p.min()}."
        )
    if np.any(variance <= 0):
        raise InvalidInputError("variance: every predictive variance must be > 0.")
    return p / p.sum(), mean, np.maximum(variance, _VARIANCE_FLOOR)


def label_information_mc(
    probabilities: FloatArray, mean: FloatArray, variance: FloatArray, draws: FloatArray
) -> FloatArray:
    """Monte Carlo estimate of I(l; y) for every candidate, with common random numbers.

    Î = Σ_l p_l (1/K) Σ_k [log N(y_lk; l) − log Σ_l' p_l' N(y_lk; l')], y_lk = m_l + √V_l ∘ ξ_k.

    Args:
        probabilities: p_l. Shape (L,).
        mean: Predictive means m_l(x). Shape (C, L, dy).
        variance: Predictive variances V_l(x) (diagonal, with noise). Shape (C, L, dy).
        draws: Standard normal draws ξ_k, shared by every candidate and object. Shape (K, dy).

    Returns:
        The estimates, in nats (clipped to [0, H(p)]). Shape (C,).
    """
    p, mean, variance = _check_mixture(probabilities, mean, variance)
    xi = as_float_array(draws, "draws", (None, mean.shape[2]))
    active = np.flatnonzero(p > 0)
    log_p = np.log(p[active])
    m, v = mean[:, active], variance[:, active]  # (C, L', dy)
    std = np.sqrt(v)
    log_v = np.log(v)
    # y[c, l, k] = m_l + σ_l ξ_k; its log-density under every component l'.
    samples = m[:, :, None, :] + std[:, :, None, :] * xi[None, None, :, :]  # (C, L', K, dy)
    # log N(y_lk; l) needs no residual: (y_lk - m_l)² / V_l = ξ_k².
    own = -0.5 * np.sum(np.log(2.0 * np.pi) + log_v, axis=2)[:, :, None] - 0.5 * np.sum(
        xi**2, axis=1
    )  # (C, L', K)
    # log p(y_lk) = logsumexp_j [log p_j + log N(y_lk; j)], accumulated one component at a time.
    mixture = np.full(own.shape, -np.inf)
    for j in range(m.shape[1]):
        residual = samples - m[:, None, None, j, :]
        log_density = -0.5 * np.sum(
            np.log(2.0 * np.pi) + log_v[:, None, None, j, :] + residual**2 / v[:, None, None, j, :],
            axis=3,
        )
        mixture = np.logaddexp(mixture, log_p[j] + log_density)
    total = np.einsum("l,clk->c", p[active], own - mixture) / xi.shape[0]
    entropy = float(-np.sum(p[active] * log_p))
    return np.asarray(np.clip(total, 0.0, entropy), dtype=np.float64)


def _pairwise_divergences(mean: FloatArray, variance: FloatArray) -> tuple[FloatArray, FloatArray]:
    """KL(i ‖ j) and the Bhattacharyya distance between diagonal Gaussians. Each (C, L, L)."""
    mi, mj = mean[:, :, None, :], mean[:, None, :, :]
    vi, vj = variance[:, :, None, :], variance[:, None, :, :]
    diff2 = (mi - mj) ** 2
    kl = 0.5 * np.sum(vi / vj + diff2 / vj - 1.0 + np.log(vj) - np.log(vi), axis=3)
    avg = 0.5 * (vi + vj)
    bhattacharyya = np.sum(
        0.125 * diff2 / avg + 0.5 * np.log(avg) - 0.25 * (np.log(vi) + np.log(vj)), axis=3
    )
    return kl, bhattacharyya


def label_information_bounds(
    probabilities: FloatArray, mean: FloatArray, variance: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Kolchinsky–Tracey pairwise bounds on I(l; y) for every candidate.

    Args:
        probabilities: p_l. Shape (L,).
        mean: Predictive means. Shape (C, L, dy).
        variance: Predictive variances (diagonal, with noise). Shape (C, L, dy).

    Returns:
        Lower (Bhattacharyya) and upper (Kullback–Leibler) bounds in nats. Each (C,).
    """
    p, mean, variance = _check_mixture(probabilities, mean, variance)
    kl, bhattacharyya = _pairwise_divergences(mean, variance)
    active = p > 0
    weights = np.log(np.where(active, p, 1.0))[None, None, :] + np.where(active, 0.0, -np.inf)

    def estimate(divergence: FloatArray) -> FloatArray:
        inner = scipy.special.logsumexp(weights - divergence, axis=2)  # (C, L)
        return np.asarray(-np.sum(np.where(active, p, 0.0) * inner, axis=1), dtype=np.float64)

    return estimate(bhattacharyya), estimate(kl)
