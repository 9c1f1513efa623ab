"""Small linear-algebra helpers: Cholesky with a jitter ladder."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.linalg.blas

from core.errors import NotPositiveDefiniteError
from core.validation import FloatArray

#: Relative jitters tried in turn, as multiples of the mean diagonal (METHOD.md, M2 findings).
JITTER_LADDER: tuple[float, ...] = (0.0, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4)


def cholesky_with_jitter(
    matrix: FloatArray, ladder: tuple[float, ...] = JITTER_LADDER, what: str = "Gram matrix"
) -> tuple[FloatArray, float]:
    """Lower Cholesky factor of a symmetric matrix, adding jitter only when needed.

    Args:
        matrix: Symmetric matrix. Shape (N, N).
        ladder: Relative jitters (multiples of the mean diagonal) tried in order.
        what: Name of the matrix for the error message.

    Returns:
        The lower factor (N, N) and the absolute jitter that was added (0.0 if none).

    Raises:
        NotPositiveDefiniteError: No jitter of the ladder made the matrix positive definite.
    """
    scale = float(np.mean(np.diag(matrix)))
    for relative in ladder:
        jitter = relative * scale
        try:
            factor = scipy.linalg.cholesky(
                matrix + jitter * np.eye(matrix.shape[0]) if jitter else matrix,
                lower=True,
                check_finite=False,
            )
        except np.linalg.LinAlgError:
            continue
        if np.all(np.isfinite(factor)):
            return np.asarray(factor, dtype=np.float64), jitter
    raise NotPositiveDefiniteError(
        f"The {what} stayed singular after adding jitter up to {ladder[-1]:g} x its mean "
        f"diagonal. Duplicate touches with very different observations, a noise variance "
        f"near zero or extreme length-scales cause this: raise the lower bound on the noise "
        f"variance or remove duplicate rows."
    )


def log_det_from_cholesky(factor: FloatArray) -> float:
    """log det A from the Cholesky factor of A."""
    return float(2.0 * np.sum(np.log(np.diag(factor))))


def _signed_roots(matrix: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Columns of ``matrix · diag(√|w|)`` split by the sign of w (zero weights dropped)."""
    root = matrix * np.sqrt(np.abs(weights))
    if np.all(weights > 0.0):
        return root, root[:, :0]
    return root[:, weights > 0.0], root[:, weights < 0.0]


def weighted_gram_difference(
    left: FloatArray, left_weights: FloatArray, right: FloatArray, right_weights: FloatArray
) -> FloatArray:
    """One triangle of A diag(a) Aᵀ - B diag(b) Bᵀ by symmetric rank-k updates (``dsyrk``).

    Half the flops of the two general products and no symmetrisation pass: the weights are
    split by sign (w = √|w| · sign(w) · √|w|), so negative weights (e.g. eigenvalues at
    round-off below zero) are handled exactly.

    Args:
        left: A. Shape (n, p).
        left_weights: a. Shape (p,).
        right: B. Shape (n, q).
        right_weights: b. Shape (q,).

    Returns:
        Shape (n, n), C-ordered: the UPPER triangle (diagonal included) holds the result and
        the strictly lower triangle is zero.
    """
    a_pos, a_neg = _signed_roots(left, left_weights)
    b_pos, b_neg = _signed_roots(right, right_weights)
    result: FloatArray | None = None
    for block, alpha in ((a_pos, 1.0), (b_neg, 1.0), (b_pos, -1.0), (a_neg, -1.0)):
        if block.shape[1] == 0:
            continue
        # dsyrk(trans=1) on the Fortran view blockᵀ (k, n) forms block blockᵀ without a copy;
        # the lower triangle of the Fortran result is the upper triangle of its C transpose.
        result = scipy.linalg.blas.dsyrk(
            alpha,
            np.ascontiguousarray(block).T,
            beta=0.0 if result is None else 1.0,
            c=result,
            trans=1,
            lower=1,
            overwrite_c=1,
        )
    if result is None:
        n = left.shape[0]
        return np.zeros((n, n))
    return np.asarray(result.T, dtype=np.float64)
