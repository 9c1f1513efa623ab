"""Starting latents for manifold fitting (METHOD.md eq. (M2), findings).

The likelihood has many local optima in S. A data-driven start does much better than a random
one: estimate each object's mean response at a common set of reference actions by kernel
smoothing over x, standardise each feature, and take the principal components of the
L × (refs · dy) matrix of smoothed responses. Random starts draw S ~ N(0, I). Every start is
returned normalised (centred, RMS distance to the centre 1).
"""

from __future__ import annotations

import numpy as np

from core.errors import InvalidInputError
from core.types import TrainingData
from core.validation import FloatArray

#: At most this many reference actions (taken from the pooled training actions).
MAX_REFERENCE_ACTIONS = 256

#: Components with a singular value below this fraction of the largest count as absent.
_RANK_TOLERANCE = 1e-8


def normalise_spread(latents: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Centre latents and scale them to RMS distance 1 from their centre.

    Args:
        latents: Shape (L, ds).

    Returns:
        (normalised latents (L, ds), the centre (ds,), the scale c with
        normalised = (latents - centre) / c). ``c`` is 1 when every latent coincides.
    """
    centre = latents.mean(axis=0)
    centred = latents - centre
    scale = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    if not np.isfinite(scale) or scale <= 1e-300:
        scale = 1.0
    return centred / scale, centre, scale


def random_latents(n_objects: int, latent_dim: int, rng: np.random.Generator) -> FloatArray:
    """S ~ N(0, I), normalised (centred, unit RMS spread). Shape (L, ds)."""
    for _ in range(100):
        draw = rng.standard_normal((n_objects, latent_dim))
        normalised, _, scale = normalise_spread(draw)
        if scale != 1.0 or np.any(normalised):
            return normalised
    raise InvalidInputError(  # pragma: no cover - a Gaussian draw is never degenerate 100 times
        "random_latents: could not draw distinct latents."
    )


def reference_actions(data: TrainingData) -> FloatArray:
    """The common reference actions: the pooled training actions, thinned evenly to at most
    :data:`MAX_REFERENCE_ACTIONS` rows (in a fixed order, so start 0 is deterministic).

    Returns:
        Shape (R, dx).
    """
    actions = data.actions
    n = actions.shape[0]
    if n <= MAX_REFERENCE_ACTIONS:
        return actions.copy()
    # Sort by the first principal direction so that thinning spreads over the action cloud.
    centred = actions - actions.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    order = np.argsort(centred @ vt[0], kind="stable")
    pick = np.linspace(0, n - 1, MAX_REFERENCE_ACTIONS).round().astype(np.intp)
    return np.asarray(actions[order[pick]], dtype=np.float64)


def smoothed_responses(data: TrainingData, references: FloatArray) -> FloatArray:
    """Nadaraya–Watson estimate of each object's mean response at the reference actions.

    The Gaussian kernel has a per-dimension bandwidth std(x_d) · n̄^(-1/(dx+4)) (Scott's rule,
    n̄ the mean number of touches per object). Weights are normalised in log space, so
    references far from an object's touches still get its nearest touches' mean.

    Args:
        data: Training touches.
        references: Reference actions. Shape (R, dx).

    Returns:
        Smoothed responses. Shape (L, R, dy).
    """
    actions = data.actions
    dx = actions.shape[1]
    std = np.std(actions, axis=0)
    std = np.where(std > 0, std, 1.0)
    mean_touches = data.n_touches / data.n_objects
    bandwidth = std * mean_touches ** (-1.0 / (dx + 4))
    scaled_refs = references / bandwidth
    scaled_actions = actions / bandwidth
    sq = (
        np.sum(scaled_refs**2, axis=1)[:, None]
        + np.sum(scaled_actions**2, axis=1)[None, :]
        - 2.0 * scaled_refs @ scaled_actions.T
    )
    log_w = -0.5 * np.maximum(sq, 0.0)  # (R, N)
    out = np.empty((data.n_objects, references.shape[0], data.observation_dim))
    for obj in range(data.n_objects):
        mask = data.object_index == obj
        lw = log_w[:, mask]
        w = np.exp(lw - lw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        out[obj] = w @ data.observations[mask]
    return out


def pca_latents(data: TrainingData, latent_dim: int, rng: np.random.Generator) -> FloatArray:
    """The data-driven start: PCA of the per-object smoothed responses (METHOD.md, M2).

    Each feature is standardised by its pooled standard deviation so features in different
    units weigh alike; the L × (R·dy) matrix is centred over objects and its leading ``ds``
    principal component scores are the latents. The centred matrix has rank ≤ L - 1: latent
    dimensions beyond its rank (e.g. ds ≥ L - 1, or objects whose smoothed responses
    coincide) are filled with small random values (0.1 of the spread) from ``rng``; if no
    component is present at all, the start is random.

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        rng: Random generator (used only for the degenerate dimensions).

    Returns:
        Normalised latents (centred, unit RMS spread). Shape (L, ds).
    """
    n_objects = data.n_objects
    responses = smoothed_responses(data, reference_actions(data))  # (L, R, dy)
    y_std = np.std(data.observations, axis=0)
    y_std = np.where(y_std > 0, y_std, 1.0)
    matrix = (responses / y_std).reshape(n_objects, -1)
    matrix = matrix - matrix.mean(axis=0)
    u, singular, _ = np.linalg.svd(matrix, full_matrices=False)
    if singular.size == 0 or singular[0] <= 0 or not np.all(np.isfinite(singular)):
        return random_latents(n_objects, latent_dim, rng)
    present = singular > _RANK_TOLERANCE * singular[0]
    scores = np.zeros((n_objects, latent_dim))
    n_used = min(latent_dim, int(np.sum(present)))
    scores[:, :n_used] = u[:, :n_used] * singular[:n_used]
    latents, _, _ = normalise_spread(scores)
    if n_used < latent_dim:
        # Dimensions the responses do not determine: small random values, so the optimiser
        # can still use them (an exact zero column would sit on a saddle by symmetry).
        extra = 0.1 * rng.standard_normal((n_objects, latent_dim - n_used))
        latents[:, n_used:] = extra - extra.mean(axis=0)
        latents, _, _ = normalise_spread(latents)
    return latents
