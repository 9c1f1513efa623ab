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
    return np.asarray(np.exp(-0.5 * scaled_squared_distance(a, b, lengthscales)), dtype=np.float64)


def scaled_squared_distance(a: FloatArray, b: FloatArray, lengthscales: FloatArray) -> FloatArray:
    """Σ_d (a_d - b_d)² / ℓ_d² between every row of ``a`` and of ``b`` (−2 × the log of
    :func:`squared_exponential`), expanded as |a/ℓ|² + |b/ℓ|² − 2 (a/ℓ)·(b/ℓ) and clamped at 0.

    Args:
        a: Points. Shape (Na, d).
        b: Points. Shape (Nb, d).
        lengthscales: ℓ (not squared). Shape (d,).

    Returns:
        Shape (Na, Nb).
    """
    a_scaled = a / lengthscales
    b_scaled = b / lengthscales
    sq = (
        np.sum(a_scaled**2, axis=1)[:, None]
        + np.sum(b_scaled**2, axis=1)[None, :]
        - 2.0 * a_scaled @ b_scaled.T
    )
    return np.asarray(np.maximum(sq, 0.0), dtype=np.float64)


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


def feature_action_kernels(
    actions: FloatArray, points: FloatArray, lengthscales: FloatArray
) -> FloatArray:
    """k^x_a(x, x_i) = exp(-½ (x - x_i)ᵀ (Λ^x_a)⁻¹ (x - x_i)) for every feature a, action x and
    point x_i.

    The squared distances are expanded, |x/ℓ|² + |x_i/ℓ|² - 2 (x/ℓ)·(x_i/ℓ), around the mean
    point (one GEMM per feature instead of a (C, N, dx) difference array).

    Args:
        actions: Shape (C, dx).
        points: Shape (N, dx).
        lengthscales: ℓ^x_a of every feature (not squared). Shape (dy, dx).

    Returns:
        Shape (dy, C, N).
    """
    inverse = 1.0 / lengthscales  # (dy, dx)
    centre = points.mean(axis=0)
    scaled_x = (actions - centre)[None, :, :] * inverse[:, None, :]  # (dy, C, dx)
    scaled_p = (points - centre)[None, :, :] * inverse[:, None, :]  # (dy, N, dx)
    exponent = scaled_x @ np.swapaxes(scaled_p, 1, 2)  # (dy, C, N)
    exponent *= 2.0
    exponent -= np.sum(scaled_x**2, axis=2)[:, :, None]
    exponent -= np.sum(scaled_p**2, axis=2)[:, None, :]
    np.minimum(exponent, 0.0, out=exponent)
    exponent *= 0.5
    return np.asarray(np.exp(exponent, out=exponent), dtype=np.float64)
