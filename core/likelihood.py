"""Negative log marginal likelihood of the object manifold and its analytic gradient (M2).

    -log p(Y | S, X, γ) = Σ_a ½ y_aᵀ K_a⁻¹ y_a + ½ log det K_a + (N/2) log 2π     METHOD.md eq. (M2)

with K_a = σ_f,a² K^s_a[obj, obj] ∘ K^x_a + σ_n,a² I (eq. (M1)) and y_a centred on the
per-feature observation mean (as :func:`core.posterior.condition` does).

Gradient. With W_a = K_a⁻¹ - β_a β_aᵀ, ∂(-log p)/∂K_a = ½ W_a. Writing M_a = W_a ∘ K_f,a for the
noise-free part K_f,a = K_a - σ_n,a² I, every derivative is a weighted sum of M_a:

* log σ_f²:   ½ Σ_ij M_ij
* log σ_n²:   ½ σ_n² tr W
* log ℓ^x_d:  ½ Σ_ij M_ij (x_id - x_jd)² / ℓ_d²  =  (Σ_i r_i x_id² - x_dᵀ M x_d) / ℓ_d², r = M 1
* log ℓ^s_d:  ½ Σ_ll' B_ll' (s_ld - s_l'd)² / ℓ_d²
* s_ld:       -Σ_l' B_ll' (s_ld - s_l'd) / ℓ_d²

where B = Pᵀ M P (P the N × L object indicator) holds the L × L block sums of M: the latent is
shared by an object's touches, so its gradient sums theirs. Everything is O(N² (dx + L)) per
feature on top of the Cholesky factor and the inverse (computed once, from the factor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from core.errors import InvalidInputError
from core.linalg import cholesky_with_jitter, log_det_from_cholesky
from core.parameters import ParameterLayout
from core.types import Hyperparameters, TrainingData
from core.validation import FloatArray, as_float_array

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class LikelihoodGradient:
    """∂(-log p)/∂ of every group of unknowns.

    Attributes:
        latents: With respect to S. Shape (L, ds).
        log_signal_variance: With respect to log σ_f². Shape (dy,).
        log_noise_variance: With respect to log σ_n². Shape (dy,).
        log_latent_lengthscales: With respect to log ℓ^s. Shape (dy, ds).
        log_action_lengthscales: With respect to log ℓ^x. Shape (dy, dx).
    """

    latents: FloatArray
    log_signal_variance: FloatArray
    log_noise_variance: FloatArray
    log_latent_lengthscales: FloatArray
    log_action_lengthscales: FloatArray


class ManifoldLikelihood:
    """-log p(Y | S, X, γ) and its gradient at packed parameter vectors (see
    :mod:`core.parameters`), with the data-only terms computed once.

    Internally the touches are sorted by object (the likelihood does not depend on their order),
    so that the L × L latent Gram matrix expands into contiguous blocks and the block sums of
    the gradient are two ``reduceat`` passes.

    Not a result type: it counts evaluations and remembers the largest jitter it needed
    (:attr:`max_jitter`), which a fit reports.

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
    """

    #: Above this many entries (dx · N²) the per-dimension squared action differences are not
    #: cached and are recomputed at every evaluation.
    CACHE_LIMIT = 16_000_000

    def __init__(self, data: TrainingData, latent_dim: int) -> None:
        if isinstance(latent_dim, bool) or int(latent_dim) != latent_dim or latent_dim < 1:
            raise InvalidInputError(f"latent_dim: must be an integer ≥ 1, received {latent_dim}.")
        self.data = data
        self.layout = ParameterLayout.for_data(data, int(latent_dim))
        order = np.argsort(data.object_index, kind="stable")
        # Centred actions: squared distances are shift invariant and lose less precision.
        actions = data.actions[order] - data.actions.mean(axis=0)
        self._actions = np.ascontiguousarray(actions)
        self._centred = np.ascontiguousarray((data.observations[order] - data.observation_mean).T)
        self._counts = data.touches_per_object()
        self._starts = np.concatenate([[0], np.cumsum(self._counts)[:-1]]).astype(np.intp)
        n, dx = actions.shape
        self._sq_actions: FloatArray | None = None
        if dx * n * n <= self.CACHE_LIMIT:
            diff = actions.T[:, :, None] - actions.T[:, None, :]  # (dx, N, N)
            self._sq_actions = np.ascontiguousarray((diff**2).reshape(dx, n * n))
        self._diag = np.arange(n) * (n + 1)
        self.max_jitter = 0.0
        self.evaluations = 0

    def noise_free_gram(self, vector: FloatArray) -> FloatArray:
        """K_f,a = σ_f,a² K^s_a[obj, obj] ∘ K^x_a for every feature, METHOD.md eq. (M1).

        Rows and columns are in the internal (object-sorted) order. Shape (dy, N, N).
        """
        latents, log_sf, _, log_ls, log_lx = self.layout.split(vector)
        dy = self.layout.observation_dim
        n = self.data.n_touches
        inv_lx2 = np.exp(-2.0 * log_lx)  # (dy, dx)
        if self._sq_actions is not None:
            if inv_lx2.shape[1] == 1:
                sq = inv_lx2[:, :1] * self._sq_actions[0][None, :]
            else:
                sq = inv_lx2 @ self._sq_actions
            sq = sq.reshape(dy, n, n)
        else:
            x_scaled = self._actions[None, :, :] * np.sqrt(inv_lx2)[:, None, :]
            norms = np.sum(x_scaled**2, axis=2)
            sq = np.empty((dy, n, n))
            for a in range(dy):
                sq[a] = norms[a][:, None] + norms[a][None, :] - 2.0 * x_scaled[a] @ x_scaled[a].T
            np.maximum(sq, 0.0, out=sq)
        sq *= -0.5
        np.exp(sq, out=sq)  # K^x_a
        diff = latents[:, None, :] - latents[None, :, :]  # (L, L, ds)
        sq_latent = np.einsum("lmd,ad->alm", diff**2, np.exp(-2.0 * log_ls))
        latent_gram = np.exp(-0.5 * sq_latent) * np.exp(log_sf)[:, None, None]  # σ_f² K^s
        for a in range(dy):
            expanded = np.repeat(
                np.repeat(latent_gram[a], self._counts, axis=0), self._counts, axis=1
            )
            sq[a] *= expanded
        return np.asarray(sq, dtype=np.float64)

    def _factor(self, gram_free: FloatArray, noise: float, feature: int) -> FloatArray:
        """Lower Cholesky factor of K_a = K_f,a + σ_n² I (jitter only if needed)."""
        gram = gram_free.copy()
        gram.ravel()[self._diag] += noise
        # Fast path: plain LAPACK on the symmetric matrix (its transpose is itself, so the
        # C-ordered array is read as Fortran without a copy). Jitter ladder only on failure.
        factor_t, info = scipy.linalg.lapack.dpotrf(gram.T, lower=0, clean=1, overwrite_a=0)
        if info == 0:
            return np.asarray(factor_t.T)
        factor, jitter = cholesky_with_jitter(gram, what=f"Gram matrix of feature {feature}")
        self.max_jitter = max(self.max_jitter, jitter)
        return factor

    def value(self, vector: FloatArray) -> float:
        """-log p at a packed vector (no gradient: one Cholesky factor per feature)."""
        self.evaluations += 1
        _, _, log_sn, _, _ = self.layout.split(vector)
        gram_free = self.noise_free_gram(vector)
        n = self.data.n_touches
        total = 0.0
        for a in range(self.layout.observation_dim):
            factor = self._factor(gram_free[a], float(np.exp(log_sn[a])), a)
            alpha = scipy.linalg.solve_triangular(
                factor, self._centred[a], lower=True, check_finite=False
            )
            # METHOD.md eq. (M2)
            total += 0.5 * float(alpha @ alpha) + 0.5 * log_det_from_cholesky(factor)
            total += 0.5 * n * _LOG_2PI
        return total

    def value_and_gradient(self, vector: FloatArray) -> tuple[float, FloatArray]:
        """-log p and its gradient with respect to the packed vector (same layout)."""
        self.evaluations += 1
        layout = self.layout
        latents, _, log_sn, log_ls, log_lx = layout.split(vector)
        noise = np.exp(log_sn)
        inv_ls2 = np.exp(-2.0 * log_ls)  # (dy, ds)
        inv_lx2 = np.exp(-2.0 * log_lx)  # (dy, dx)
        gram_free = self.noise_free_gram(vector)
        n = self.data.n_touches
        dy = layout.observation_dim
        g_latents = np.zeros((layout.n_objects, layout.latent_dim))
        g_sf = np.empty(dy)
        g_sn = np.empty(dy)
        g_ls = np.empty((dy, layout.latent_dim))
        g_lx = np.empty((dy, layout.action_dim))
        sq_pair = (latents[:, None, :] - latents[None, :, :]) ** 2  # (L, L, ds)
        total = 0.0
        for a in range(dy):
            factor = self._factor(gram_free[a], float(noise[a]), a)
            upper = factor.T  # Fortran-ordered upper factor: what LAPACK reads without copying
            y = self._centred[a]
            beta, info = scipy.linalg.lapack.dpotrs(upper, y, lower=0)
            # METHOD.md eq. (M2)
            log_det = 2.0 * float(np.sum(np.log(factor.ravel()[self._diag])))
            total += 0.5 * float(y @ beta) + 0.5 * log_det + 0.5 * n * _LOG_2PI
            # K⁻¹ from the factor: dpotri fills the upper triangle of the Fortran array, i.e.
            # the lower triangle of its C-ordered transpose; the rest stays zero (clean factor).
            inverse_t, info2 = scipy.linalg.lapack.dpotri(upper, lower=0, overwrite_c=0)
            if info or info2:  # pragma: no cover - the factor came from a successful Cholesky
                raise InvalidInputError(f"dpotrs/dpotri failed on feature {a}.")
            lower = inverse_t.T
            w = np.add(lower, lower.T, order="C")
            w.ravel()[self._diag] -= lower.ravel()[self._diag]
            w -= np.multiply.outer(beta, beta)  # W = K⁻¹ - ββᵀ;  ∂(-log p)/∂K = ½ W
            g_sn[a] = 0.5 * noise[a] * float(w.ravel()[self._diag].sum())
            m = w
            m *= gram_free[a]  # M = W ∘ K_f
            g_sf[a] = 0.5 * float(m.sum())
            if self._sq_actions is not None:
                g_lx[a] = 0.5 * (self._sq_actions @ m.ravel()) * inv_lx2[a]
            else:
                x = self._actions
                g_lx[a] = (m.sum(axis=1) @ x**2 - np.sum(x * (m @ x), axis=0)) * inv_lx2[a]
            blocks = np.add.reduceat(
                np.add.reduceat(m, self._starts, axis=0), self._starts, axis=1
            )  # B = Pᵀ M P, (L, L)
            g_ls[a] = 0.5 * np.einsum("lm,lmd->d", blocks, sq_pair) * inv_ls2[a]
            g_latents -= (latents * blocks.sum(axis=1)[:, None] - blocks @ latents) * inv_ls2[a]
        grad = np.empty(layout.size)
        grad[layout.latents] = g_latents.ravel()
        grad[layout.log_signal_variance] = g_sf
        grad[layout.log_noise_variance] = g_sn
        grad[layout.log_latent_lengthscales] = g_ls.ravel()
        grad[layout.log_action_lengthscales] = g_lx.ravel()
        return total, grad


def negative_log_likelihood(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> float:
    """-Σ_a log p(y_a | S, X, γ_a), METHOD.md eq. (M2).

    Args:
        data: Training touches (N of them, L objects).
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.

    Returns:
        The negative log marginal likelihood; equals ``-condition(...).log_likelihood``.
    """
    likelihood, vector = _prepare(data, latents, hyperparameters)
    return likelihood.value(vector)


def negative_log_likelihood_and_gradient(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> tuple[float, LikelihoodGradient]:
    """-log p and its analytic gradient with respect to S and the log-hyperparameters.

    Args:
        data: Training touches.
        latents: Object latents. Shape (L, ds).
        hyperparameters: Per-feature hyperparameters.

    Returns:
        The value and a :class:`LikelihoodGradient` (gradients with respect to the logs of
        σ_f², σ_n² and of the length-scales themselves, not of their squares).
    """
    likelihood, vector = _prepare(data, latents, hyperparameters)
    value, grad = likelihood.value_and_gradient(vector)
    s, sf, sn, ls, lx = likelihood.layout.split(grad)
    return value, LikelihoodGradient(
        latents=s.copy(),
        log_signal_variance=sf.copy(),
        log_noise_variance=sn.copy(),
        log_latent_lengthscales=ls.copy(),
        log_action_lengthscales=lx.copy(),
    )


def _prepare(
    data: TrainingData, latents: FloatArray, hyperparameters: Hyperparameters
) -> tuple[ManifoldLikelihood, FloatArray]:
    h = hyperparameters
    latents = as_float_array(latents, "latents", (data.n_objects, h.latent_dim))
    likelihood = ManifoldLikelihood(data, h.latent_dim)
    return likelihood, likelihood.layout.pack(latents, h)
