"""The product squared-exponential kernel of docs/method.md eq. (M1), factor by factor.

k_a(z, z') = σ_f,a² · k^s_a(s, s') · k^x_a(x, x'), with both factors ARD squared exponentials.
"""

from __future__ import annotations

import numpy as np

from core.validation import FloatArray


def squared_exponential(a: FloatArray, b: FloatArray, lengthscales: FloatArray) -> FloatArray:
    """exp(-½ Σ_d (a_d - b_d)² / ℓ_d²) between every row of ``a`` and of ``b``.

    Args:
        a: Points. Shape (Na, d).
        b: Points. Shape (Nb, d).
        lengthscales: ℓ (not squared). Shape (d,).

    Returns:
        Kernel matrix. Shape (Na, Nb).
    """
    a_scaled = a / lengthscales
    b_scaled = b / lengthscales
    sq = (
        np.sum(a_scaled**2, axis=1)[:, None]
        + np.sum(b_scaled**2, axis=1)[None, :]
        - 2.0 * a_scaled @ b_scaled.T
    )
    return np.asarray(np.exp(-0.5 * np.maximum(sq, 0.0)), dtype=np.float64)


def squared_distances(a: FloatArray, b: FloatArray, lengthscales: FloatArray) -> FloatArray:
    """Per-dimension scaled squared differences (a_d - b_d)² / ℓ_d².

    Args:
        a: Points. Shape (Na, d).
        b: Points. Shape (Nb, d).
        lengthscales: ℓ. Shape (d,).

    Returns:
        Shape (d, Na, Nb); useful for gradients with respect to log ℓ_d.
    """
    diff = (a[:, None, :] - b[None, :, :]) / lengthscales
    return np.asarray(np.moveaxis(diff**2, -1, 0), dtype=np.float64)
