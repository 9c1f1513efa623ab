"""The Kronecker likelihood for few objects: L Cholesky blocks instead of eigendecomposing K^x.

On a shared design the noisy Gram matrix of feature a is σ_f² K^s ⊗ K^x + σ_n² I
(:mod:`core.gp.kronecker`). Rotating by the eigenvectors of the small L × L latent kernel alone,
K^s = U_s Λ_s U_sᵀ, makes it block diagonal:

    (U_s ⊗ I)ᵀ K_a (U_s ⊗ I) = blockdiag_j B_j,    B_j = σ_f² λ_j K^x + σ_n² I    (M × M)

so with Ŷ = U_sᵀ Y (L × M, rows ŷ_j) and A the L × M matrix of rows α_j = B_j⁻¹ ŷ_j:

* log det K_a = Σ_j log det B_j;  yᵀ K_a⁻¹ y = Σ_j ŷ_j · α_j;  β = U_s A;
* the block sums of W ∘ K_f that the gradient needs (:mod:`core.gp.kronecker`'s docstring), with
  w_s[j] = ⟨K^x, B_j⁻¹⟩ (Frobenius):

      Ω_s = U_s (diag(w_s) - A K^x Aᵀ) U_sᵀ                                    (L × L)
      Ω_x = Σ_j λ_j B_j⁻¹ - Aᵀ Λ_s A                                           (M × M)

  and tr W = Σ_j tr B_j⁻¹ - ‖A‖².

Each block costs a Cholesky factorisation and an inverse from it, about M³ flops at a large
fraction of the GEMM rate; the eigendecomposition of K^x costs ~9 M³ at a much lower one
(``dsyevd`` at M = 100 took ~1.2 ms here, a Cholesky factorisation and inverse ~0.16 ms). So the
blocks win for a handful of objects (:func:`use_blocks`), the usual lab case of a few objects
each touched with the same 100 actions; the eigendecompositions win beyond. Exact either way:
the tests match the eigendecomposition path to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg.lapack

from core.errors import NotPositiveDefiniteError
from core.gp.linalg import inverse_from_cholesky
from core.validation import FloatArray

_LOG_2PI = float(np.log(2.0 * np.pi))
#: The blocks are used for at most this many objects ...
BLOCK_MAX_OBJECTS = 4
#: ... and designs of at least this many actions (see :func:`use_blocks`).
BLOCK_MIN_ACTIONS = 50
#: Blocks are used only where the eigendecomposition path would add no jitter: the noise
#: variance above this fraction of σ_f² + σ_n² bounds every block's smallest eigenvalue away
#: from that path's floor (1e-14 of σ_f² + σ_n², :mod:`core.gp.kronecker`) by orders of
#: magnitude.
NOISE_FRACTION_FLOOR = 1e-10


def use_blocks(n_objects: int, n_actions: int) -> bool:
    """Whether L Cholesky blocks of order M beat eigendecomposing K^x.

    Measured here (one value and gradient, one BLAS thread): a Cholesky factorisation and
    inverse cost 1/6-1/7 of ``dsyevd`` at M = 50-200, but each block carries ~0.1 ms of
    bookkeeping. The blocks were 1.3-1.9x faster for L = 2-3 and 1.1-1.3x for L = 4 at
    M = 50-200, about even at L = 6, slower at L = 8 and at M = 25 with L ≥ 3.
    """
    return n_objects <= BLOCK_MAX_OBJECTS and n_actions >= BLOCK_MIN_ACTIONS


@dataclass(frozen=True)
class BlockSums:
    """What the gradient of -log p needs, per feature (as :mod:`core.gp.kronecker` computes it).

    Attributes:
        value: -log p.
        noise_trace: tr W_a = Σ 1/D - ‖β‖² per feature. Shape (dy,).
        latent_half: Upper triangles of K^s ∘ Ω_s (strictly lower zero). Shape (dy, L, L).
        action_half: Upper triangles of K^x ∘ Ω_x (strictly lower zero). Shape (dy, M, M).
    """

    value: float
    noise_trace: FloatArray
    latent_half: FloatArray
    action_half: FloatArray


def _factor_blocks(
    latent_values: FloatArray, action_gram: FloatArray, signal: float, noise: float
) -> list[FloatArray] | None:
    """Upper Cholesky factors (Fortran-ordered) of B_j = σ_f² λ_j K^x + σ_n² I, or ``None``
    when the noise is too small for the blocks or a factorisation fails."""
    if noise <= NOISE_FRACTION_FLOOR * (signal + noise):
        return None
    m = action_gram.shape[0]
    factors = []
    for value in latent_values:
        block = (signal * value) * action_gram.T  # Fortran-ordered (K^x is symmetric)
        block.ravel(order="K")[:: m + 1] += noise  # the diagonal, through a strided view
        factor, info = scipy.linalg.lapack.dpotrf(block, lower=0, overwrite_a=1, clean=1)
        if info != 0:
            return None
        factors.append(factor)
    return factors


def _latent_eigh(latent_gram: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eigenvalues (dy, L) and eigenvectors (dy, L, L) of each feature's small K^s, by LAPACK
    ``dsyevd`` directly (for a few 4 × 4 matrices ``numpy.linalg.eigh``'s overhead is most of
    its time)."""
    dy, n_objects, _ = latent_gram.shape
    values = np.empty((dy, n_objects))
    vectors = np.empty((dy, n_objects, n_objects))
    for a in range(dy):
        w, v, info = scipy.linalg.lapack.dsyevd(latent_gram[a], compute_v=1, lower=1)
        if info != 0:  # pragma: no cover - a symmetric matrix with finite entries
            raise NotPositiveDefiniteError(f"dsyevd failed on feature {a} (info {info}).")
        values[a], vectors[a] = w, v
    return values, vectors


def _log_det(factors: list[FloatArray]) -> float:
    """Σ_j log det B_j from the Cholesky factors."""
    diagonals = np.array([np.diagonal(factor) for factor in factors])
    return float(2.0 * np.sum(np.log(diagonals)))


def block_value(
    latent_gram: FloatArray,
    action_gram: FloatArray,
    grid_y: FloatArray,
    signal: FloatArray,
    noise: FloatArray,
) -> float | None:
    """-log p, or ``None`` where the blocks do not apply (see :func:`block_sums`)."""
    latent_values, latent_vectors = _latent_eigh(latent_gram)
    rotated = np.swapaxes(latent_vectors, 1, 2) @ grid_y  # Ŷ (dy, L, M)
    total = 0.5 * grid_y.size * _LOG_2PI
    for a in range(grid_y.shape[0]):
        factors = _factor_blocks(latent_values[a], action_gram[a], signal[a], noise[a])
        if factors is None:
            return None
        for factor, y_hat in zip(factors, rotated[a], strict=True):
            alpha, _ = scipy.linalg.lapack.dpotrs(factor, y_hat, lower=0)
            total += 0.5 * float(y_hat @ alpha)
        total += 0.5 * _log_det(factors)
    return total


def block_sums(
    latent_gram: FloatArray,
    action_gram: FloatArray,
    grid_y: FloatArray,
    signal: FloatArray,
    noise: FloatArray,
) -> BlockSums | None:
    """-log p and the block sums of its gradient through L Cholesky blocks per feature.

    Args:
        latent_gram: K^s per feature, unit diagonal. Shape (dy, L, L).
        action_gram: K^x per feature, unit diagonal. Shape (dy, M, M).
        grid_y: Centred observations on the grid. Shape (dy, L, M).
        signal: σ_f² per feature. Shape (dy,).
        noise: σ_n² per feature. Shape (dy,).

    Returns:
        The sums, or ``None`` when a feature's noise variance is below
        :data:`NOISE_FRACTION_FLOOR` of σ_f² + σ_n² or a block is not positive definite: the
        caller then uses the eigendecompositions, whose jitter ladder handles those cases.
    """
    dy, n_objects, m = grid_y.shape
    latent_values, latent_vectors = _latent_eigh(latent_gram)
    rotated = np.swapaxes(latent_vectors, 1, 2) @ grid_y  # Ŷ (dy, L, M)
    total = 0.5 * grid_y.size * _LOG_2PI
    noise_trace = np.empty(dy)
    latent_half = np.empty((dy, n_objects, n_objects))
    action_half = np.empty((dy, m, m))
    for a in range(dy):
        factors = _factor_blocks(latent_values[a], action_gram[a], signal[a], noise[a])
        if factors is None:
            return None
        kx = action_gram[a]
        alpha = np.empty((n_objects, m))  # A, rows α_j = B_j⁻¹ ŷ_j
        inverse_sum = np.zeros((m, m), order="F")  # Σ_j λ_j B_j⁻¹, upper triangle
        w_s = np.empty(n_objects)
        trace = 0.0
        for j, factor in enumerate(factors):
            alpha[j], _ = scipy.linalg.lapack.dpotrs(factor, rotated[a, j], lower=0)
            inverse = inverse_from_cholesky(factor)  # upper triangle, strictly lower zero
            trace_j = float(np.trace(inverse))
            trace += trace_j
            # ⟨K^x, B_j⁻¹⟩ from one triangle (K^x symmetric with a unit diagonal)
            w_s[j] = 2.0 * float(np.vdot(inverse.T, kx)) - trace_j
            inverse_sum += latent_values[a, j] * inverse
        total += 0.5 * float(np.vdot(rotated[a], alpha)) + 0.5 * _log_det(factors)
        noise_trace[a] = trace - float(np.vdot(alpha, alpha))
        vectors = latent_vectors[a]
        inner = np.diag(w_s) - (alpha @ kx) @ alpha.T
        latent_half[a] = np.triu(latent_gram[a] * (vectors @ inner @ vectors.T))
        # K^x ∘ Ω_x, Ω_x = Σ_j λ_j B_j⁻¹ - Aᵀ Λ_s A, upper triangle (the lower one zeroed by
        # the upper triangle of K^x)
        inverse_sum -= (alpha.T * latent_values[a]) @ alpha
        np.multiply(np.triu(kx), inverse_sum, out=action_half[a])
    return BlockSums(
        value=total, noise_trace=noise_trace, latent_half=latent_half, action_half=action_half
    )
