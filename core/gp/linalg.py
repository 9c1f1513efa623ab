"""Small linear-algebra helpers: Cholesky with a jitter ladder, the inverse from a Cholesky
factor by GEMMs, and weighted Gram differences by symmetric rank-k updates."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.linalg.blas

from core.errors import NotPositiveDefiniteError
from core.gp.unlocked_lapack import lauum_upper, potri_upper, trtri_upper
from core.validation import FloatArray

#: Relative jitters tried in turn, as multiples of the mean diagonal (docs/method.md, M2 findings).
JITTER_LADDER: tuple[float, ...] = (0.0, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4)


def cholesky_with_jitter(
    matrix: FloatArray,
    ladder: tuple[float, ...] = JITTER_LADDER,
    what: str = "Gram matrix",
    *,
    scale: float | None = None,
    scale_name: str = "its mean diagonal",
    advice: str = (
        "Duplicate touches with very different observations, a noise variance near zero or "
        "extreme length-scales cause this: raise the lower bound on the noise variance or "
        "remove duplicate rows."
    ),
) -> tuple[FloatArray, float]:
    """Lower Cholesky factor of a symmetric matrix, adding jitter only when needed.

    Args:
        matrix: Symmetric matrix. Shape (N, N).
        ladder: Relative jitters (multiples of ``scale``) tried in order.
        what: Name of the matrix for the error message.
        scale: What the relative jitters multiply (default: the mean diagonal).
        scale_name: How the error message names ``scale``.
        advice: What the error message suggests.

    Returns:
        The lower factor (N, N) and the absolute jitter that was added (0.0 if none).

    Raises:
        NotPositiveDefiniteError: No jitter of the ladder made the matrix positive definite.
    """
    if scale is None:
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
        f"The {what} stayed singular after adding jitter up to {ladder[-1]:g} x {scale_name}. "
        f"{advice}"
    )


def log_det_from_cholesky(factor: FloatArray) -> float:
    """log det A from the Cholesky factor of A."""
    return float(2.0 * np.sum(np.log(np.diag(factor))))


#: Orders up to which :func:`weighted_gram_difference` uses plain products (call overhead).
_SMALL_GRAM = 32


def gaussian_log_density(residual: FloatArray, cov: FloatArray, what: str) -> float:
    """log N(residual; 0, cov) through a Cholesky factor, jittered if need be
    (:func:`cholesky_with_jitter`; ``what`` names the matrix in its error).

    Args:
        residual: Shape (n,).
        cov: Symmetric positive (semi-)definite. Shape (n, n).
    """
    factor, _ = cholesky_with_jitter(cov, what=what)
    z = scipy.linalg.solve_triangular(factor, residual, lower=True, check_finite=False)
    return float(
        -0.5 * float(z @ z)
        - float(np.sum(np.log(np.diag(factor))))
        - 0.5 * residual.size * np.log(2.0 * np.pi)
    )


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
    n = left.shape[0]
    if n <= _SMALL_GRAM:  # two tiny GEMMs beat four BLAS calls and the sign split
        full = (left * left_weights) @ left.T - (right * right_weights) @ right.T
        return np.triu(full)
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
        return np.zeros((n, n))
    return np.asarray(result.T, dtype=np.float64)


#: Triangles up to this order are inverted by LAPACK ``dtrtri`` directly; larger ones by
#: halves, with the off-diagonal block by two GEMMs (``dtrtri`` of OpenBLAS runs at a fraction
#: of the GEMM rate: at order 400 the recursion is ~2x faster).
TRIANGULAR_BLOCK = 64
#: Above this order :func:`inverse_from_cholesky` calls LAPACK ``dpotri``. Measured with the
#: scipy-openblas 0.3.31 wheel (AMD EPYC, one thread, interleaved medians): the recursion wins
#: 1.1-1.2x at orders 100-300, the two break even at 400-500 (±5-10 %), ``dpotri`` wins
#: 1.2-1.6x at 600-1000. (An older OpenBLAS measured the recursion 1.2x faster at 800; the
#: crossover is BLAS-specific.) Where they break even the recursion is kept: the two differ in
#: round-off, and a fit's choice among its starts is sensitive to round-off (bench/fit_n800.py).
RECURSIVE_INVERSE_MAX = 512


def upper_triangular_inverse(upper: FloatArray) -> FloatArray:
    """U⁻¹ of an invertible upper-triangular U, by recursive halving:

        [[A, B], [0, C]]⁻¹ = [[A⁻¹, -A⁻¹ B C⁻¹], [0, C⁻¹]]

    (the blocked algorithm of LAPACK's ``dtrtri``, with GEMMs for the off-diagonal block).

    Args:
        upper: U; its strictly lower triangle must be zero. Shape (n, n).

    Returns:
        U⁻¹, Fortran-ordered, strictly lower triangle zero. Shape (n, n).
    """
    n = upper.shape[0]
    if n <= TRIANGULAR_BLOCK:
        inverse = np.array(upper, dtype=np.float64, order="F")  # a copy: dtrtri works in place
        info = trtri_upper(inverse)
        if info != 0:
            raise NotPositiveDefiniteError(
                f"dtrtri: the triangular factor is singular (info {info})."
            )
        return inverse
    half = n // 2 if n < 64 else n // 32 * 16  # aligned blocks for the GEMMs, 0 < half < n
    first = upper_triangular_inverse(upper[:half, :half])
    second = upper_triangular_inverse(upper[half:, half:])
    out = np.zeros((n, n), order="F")
    out[:half, :half] = first
    out[half:, half:] = second
    np.matmul(-(first @ upper[:half, half:]), second, out=out[:half, half:])
    return out


def inverse_from_cholesky(upper: FloatArray, overwrite: bool = False) -> FloatArray:
    """A⁻¹ = U⁻¹ U⁻ᵀ from the upper Cholesky factor of A = UᵀU (``dpotri`` by
    :func:`upper_triangular_inverse` and LAPACK ``dlauum``), the O(n³) LAPACK calls without
    the GIL (:mod:`core.gp.unlocked_lapack`).

    Args:
        upper: U, Fortran-ordered for speed; strictly lower triangle zero. Shape (n, n).
        overwrite: Let LAPACK ``dpotri`` work in ``upper``'s memory (no copy of the
            factor); ``upper`` is then lost. Only orders above :data:`RECURSIVE_INVERSE_MAX`
            reach ``dpotri``.

    Returns:
        Fortran-ordered (n, n): the upper triangle (diagonal included) holds A⁻¹, the strictly
        lower triangle is zero. Its C-ordered transpose has A⁻¹ in the lower triangle.
    """
    if upper.shape[0] > RECURSIVE_INVERSE_MAX:
        product = upper if overwrite and upper.flags.f_contiguous else upper.copy(order="F")
        info = potri_upper(product)
        if info != 0:
            raise NotPositiveDefiniteError(f"dpotri: the factor is singular (info {info}).")
        return product
    inverse_u = upper_triangular_inverse(upper)  # Fortran-ordered, as dlauum works in place
    lauum_upper(inverse_u)  # fails only on bad arguments, which checked_square refuses first
    return inverse_u
