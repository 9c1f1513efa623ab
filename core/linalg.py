"""Small linear-algebra helpers: Cholesky with a jitter ladder."""

from __future__ import annotations

import numpy as np
import scipy.linalg

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
