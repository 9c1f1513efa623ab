"""The paper's appendix formula for U1 and U2, evaluated directly over all N touches.

This is the reference the structured, batched implementation in :mod:`core.recognition.moments` is
tested and benchmarked against. It follows the appendix (as restated in docs/method.md eq.
(M3)–(M4)) term by term, with no use of the per-object structure: q_ai and Q_ab,ij are built for
every touch i, j (vectorised over i and j, looped over the features a, b), β_a and K_a⁻¹ are
recomputed from the Gram matrix, the cross-covariance comes from λ_a (C = Λ - μ mᵀ) and the mutual
information from the determinant form ½ log(det S det Σ / det Σ̃). Slow on purpose: O(dy² N² ds) per
action.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.gp import gram_matrix
from core.types import GaussianBelief, ManifoldModel
from core.validation import FloatArray


@dataclass(frozen=True)
class DirectMoments:
    """Moments of one action from the direct formula.

    Attributes:
        mean: m, including the constant mean. Shape (dy,).
        cov: S, including the noise. Shape (dy, dy).
        cross_cov: C = Λ - μ mᵀ (centred m). Shape (ds, dy).
        mutual_information: U1 in nats.
    """

    mean: FloatArray
    cov: FloatArray
    cross_cov: FloatArray
    mutual_information: float


def _gram_inverse_and_beta(model: ManifoldModel) -> tuple[list[FloatArray], list[FloatArray]]:
    data, h = model.data, model.hyperparameters
    centred = data.observations - data.observation_mean
    inverses: list[FloatArray] = []
    betas: list[FloatArray] = []
    for a in range(h.observation_dim):
        gram = gram_matrix(data, model.latents, h, a)
        gram += model.posterior.jitter[a] * np.eye(data.n_touches)
        inverses.append(np.asarray(np.linalg.inv(gram), dtype=np.float64))
        betas.append(np.asarray(np.linalg.solve(gram, centred[:, a]), dtype=np.float64))
    return inverses, betas


def direct_moments(
    model: ManifoldModel,
    belief: GaussianBelief,
    action: FloatArray,
    precomputed: tuple[list[FloatArray], list[FloatArray]] | None = None,
) -> DirectMoments:
    """m, S, C and U1 of one action by the appendix formula (docs/method.md eq. (M3), (M4)).

    Args:
        model: A conditioned model.
        belief: s ~ N(μ, Σ).
        action: x. Shape (dx,).
        precomputed: (K_a⁻¹ list, β_a list) to reuse across actions; recomputed when ``None``.
    """
    data, h = model.data, model.hyperparameters
    inverses, betas = precomputed if precomputed is not None else _gram_inverse_and_beta(model)
    mu, sigma = belief.mean, belief.cov
    ds, dy = mu.shape[0], h.observation_dim
    s = model.latents[data.object_index]  # s^(i), (N, ds): eq. (4), each s_l repeated N_l times
    x = np.asarray(action, dtype=np.float64)
    identity = np.eye(ds)
    sigma_inv = np.linalg.inv(sigma)

    lam_s = [np.diag(h.latent_lengthscales[a] ** 2) for a in range(dy)]  # Λ^s_a
    lam_x = [np.diag(h.action_lengthscales[a] ** 2) for a in range(dy)]  # Λ^x_a
    alpha_sq = h.signal_variance

    e = []  # e_ai(x)
    for a in range(dy):
        dx_i = x[None, :] - data.actions
        e.append(np.exp(-0.5 * np.einsum("ni,ij,nj->n", dx_i, np.linalg.inv(lam_x[a]), dx_i)))

    q, m_centred = [], np.empty(dy)
    for a in range(dy):
        diff = mu[None, :] - s
        quad = np.einsum("ni,ij,nj->n", diff, np.linalg.inv(sigma + lam_s[a]), diff)
        det = np.linalg.det(sigma @ np.linalg.inv(lam_s[a]) + identity)
        q.append(alpha_sq[a] * det**-0.5 * np.exp(-0.5 * quad) * e[a])
        m_centred[a] = betas[a] @ q[a]

    cov = np.empty((dy, dy))
    for a in range(dy):
        for b in range(dy):
            inv_a, inv_b = np.linalg.inv(lam_s[a]), np.linalg.inv(lam_s[b])
            det = np.linalg.det((inv_a + inv_b) @ sigma + identity)
            lam_sum_inv = np.linalg.inv(lam_s[a] + lam_s[b])
            sep = s[:, None, :] - s[None, :, :]  # s_i - s_j
            sep_quad = np.einsum("ijd,de,ije->ij", sep, lam_sum_inv, sep)
            s_bar = (s @ (lam_s[b] @ lam_sum_inv).T)[:, None, :] + (s @ (lam_s[a] @ lam_sum_inv).T)[
                None, :, :
            ]
            r_inv = np.linalg.inv(np.linalg.inv(inv_a + inv_b) + sigma)
            centred = s_bar - mu
            mean_quad = np.einsum("ijd,de,ije->ij", centred, r_inv, centred)
            q_ab = (
                alpha_sq[a]
                * alpha_sq[b]
                * det**-0.5
                * np.exp(-0.5 * sep_quad - 0.5 * mean_quad)
                * e[a][:, None]
                * e[b][None, :]
            )
            cov[a, b] = betas[a] @ q_ab @ betas[b] - m_centred[a] * m_centred[b]
            if a == b:
                # K_a is the noisy Gram matrix: the noise is counted once (docs/method.md (M3)).
                cov[a, b] += alpha_sq[a] - np.trace(inverses[a] @ q_ab) + h.noise_variance[a]

    big_lambda = np.empty((ds, dy))
    for a in range(dy):
        inv_a = np.linalg.inv(lam_s[a])
        mixed = np.linalg.inv(inv_a + sigma_inv)
        points = (s @ inv_a.T + (sigma_inv @ mu)[None, :]) @ mixed.T  # (N, ds)
        big_lambda[:, a] = np.sum((betas[a] * q[a])[:, None] * points, axis=0)
    cross = big_lambda - np.outer(mu, m_centred)

    joint = np.block([[cov, cross.T], [cross, sigma]])  # Σ̃
    _, logdet_joint = np.linalg.slogdet(joint)
    _, logdet_s = np.linalg.slogdet(cov)
    _, logdet_sigma = np.linalg.slogdet(sigma)
    mi = -0.5 * (logdet_joint - logdet_s - logdet_sigma)
    return DirectMoments(
        mean=m_centred + data.observation_mean,
        cov=cov,
        cross_cov=cross,
        mutual_information=float(mi),
    )


def direct_moments_batch(
    model: ManifoldModel, belief: GaussianBelief, actions: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`direct_moments` for C actions (a Python loop over them).

    Returns:
        mean (C, dy), cov (C, dy, dy), cross_cov (C, ds, dy), mutual information (C,).
    """
    precomputed = _gram_inverse_and_beta(model)
    results = [direct_moments(model, belief, x, precomputed) for x in np.asarray(actions)]
    return (
        np.stack([r.mean for r in results]),
        np.stack([r.cov for r in results]),
        np.stack([r.cross_cov for r in results]),
        np.array([r.mutual_information for r in results]),
    )
