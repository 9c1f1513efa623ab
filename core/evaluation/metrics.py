"""Comparing a learned manifold with the ground truth (identifiable only up to similarity)."""

from __future__ import annotations

import numpy as np
import scipy.linalg

from core.errors import InvalidInputError
from core.validation import FloatArray, as_float_array


def abs_correlation(truth: FloatArray, latents: FloatArray) -> float:
    """|corr(θ, s)| for one-dimensional latents (the paper's measure for Experiment 1).

    Args:
        truth: True object parameters. Shape (L,) or (L, 1).
        latents: Learned latents. Shape (L,) or (L, 1).
    """
    a = np.ravel(as_float_array(truth, "truth", (None,) * np.ndim(truth)))
    b = np.ravel(as_float_array(latents, "latents", (None,) * np.ndim(latents)))
    if a.shape != b.shape or a.shape[0] < 2:
        raise InvalidInputError(
            f"truth and latents: need the same number (≥ 2) of 1-D points, received "
            f"{np.shape(truth)} and {np.shape(latents)}."
        )
    return float(abs(np.corrcoef(a, b)[0, 1]))


def procrustes_r2(truth: FloatArray, latents: FloatArray) -> float:
    """Fraction of the truth's spread explained after the best similarity map of the latents.

    Centres both, finds the orthogonal map and scale that best match ``latents`` to ``truth``
    (orthogonal Procrustes), and returns 1 - residual / total sum of squares (1 = perfect).

    Args:
        truth: Shape (L, d_true).
        latents: Shape (L, ds). Padded with zeros when ds < d_true.
    """
    t = as_float_array(truth, "truth", (None, None))
    s = as_float_array(latents, "latents", (t.shape[0], None))
    if s.shape[1] < t.shape[1]:
        s = np.hstack([s, np.zeros((s.shape[0], t.shape[1] - s.shape[1]))])
    t = t - t.mean(axis=0)
    s = s - s.mean(axis=0)
    rotation, _ = scipy.linalg.orthogonal_procrustes(s, t)
    mapped = s @ rotation
    denom = float(np.sum(mapped**2))
    scale = float(np.sum(mapped * t)) / denom if denom > 0 else 0.0
    residual = float(np.sum((scale * mapped - t) ** 2))
    total = float(np.sum(t**2))
    return 1.0 - residual / total if total > 0 else 0.0
