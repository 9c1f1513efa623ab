"""Starting latents for manifold fitting (docs/method.md eq. (M2), findings).

The likelihood has many local optima in S. A data-driven start does much better than a random
one: estimate each object's mean response at a common set of reference actions by kernel
smoothing over x, standardise each feature, and embed the L rows of the L × (refs · dy) matrix
of smoothed responses (the object *profiles*) in ds dimensions.

* :func:`pca_latents` — their principal components (docs/method.md). A linear map of a curved
  manifold: with many objects it folds it. On Experiment-2-like worlds (ds = 2, dx = 6,
  dy = 5, a shared design of M = 100 actions) the PCA start's Procrustes R² against the true
  latents is 0.75 / 0.60 / 0.56 at L = 20 / 100 / 400, and the fit from it stays folded
  (L = 100: log-likelihood 38,571 against 49,976 at the optimum reached from the truth).
* :func:`isomap_latents` — Isomap: geodesic distances along the k-nearest-neighbour graph of
  the profiles, embedded by classical MDS, with k chosen by the lowest residual variance
  (1 - corr² of geodesic and embedded distances) among connected graphs. Start R² 0.96 /
  0.99 / 0.95 on the same worlds; the L = 100 fit from it reaches 50,006 in 7 s (17.6 s from
  PCA).
* :func:`data_driven_starts` — the data-driven starts of a fit: Isomap and PCA from
  :data:`ISOMAP_MIN_OBJECTS` objects on, PCA alone below (with few objects every
  neighbourhood graph is nearly complete, and the Isomap of the complete graph is PCA:
  classical MDS of Euclidean distances).

Random starts draw S ~ N(0, I). Every start is returned normalised (centred, RMS distance to
the centre 1).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.csgraph
import scipy.spatial.distance

from core.errors import InvalidInputError
from core.gp.kernels import scaled_squared_distance
from core.types import TrainingData
from core.validation import FloatArray

#: At most this many reference actions (taken from the pooled training actions).
MAX_REFERENCE_ACTIONS = 256

#: Components with a singular value below this fraction of the largest count as absent.
_RANK_TOLERANCE = 1e-8

#: From this many objects on, start 0 is :func:`isomap_latents`; below, :func:`pca_latents`.
ISOMAP_MIN_OBJECTS = 8

#: Neighbour counts k tried by :func:`isomap_latents` (each capped at L - 1).
ISOMAP_NEIGHBOURS = (4, 5, 6, 8, 10, 12)


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
    log_w = -0.5 * scaled_squared_distance(references, actions, bandwidth)  # (R, N)
    out = np.empty((data.n_objects, references.shape[0], data.observation_dim))
    for obj in range(data.n_objects):
        mask = data.object_index == obj
        lw = log_w[:, mask]
        w = np.exp(lw - lw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        out[obj] = w @ data.observations[mask]
    return out


def object_profiles(data: TrainingData) -> FloatArray:
    """Each object's smoothed responses at the reference actions, every feature divided by its
    pooled standard deviation (so features in different units weigh alike), one row per object.

    Returns:
        Shape (L, R · dy).
    """
    responses = smoothed_responses(data, reference_actions(data))  # (L, R, dy)
    y_std = np.std(data.observations, axis=0)
    y_std = np.where(y_std > 0, y_std, 1.0)
    return (responses / y_std).reshape(data.n_objects, -1)


def _latents_from_scores(
    scores: FloatArray, n_used: int, latent_dim: int, rng: np.random.Generator
) -> FloatArray:
    """Normalised latents from the first ``n_used`` columns of ``scores`` (L, latent_dim);
    the dimensions beyond get small random values (0.1 of the spread) from ``rng``, so the
    optimiser can still use them (an exact zero column would sit on a saddle by symmetry)."""
    latents, _, _ = normalise_spread(scores)
    if n_used < latent_dim:
        extra = 0.1 * rng.standard_normal((scores.shape[0], latent_dim - n_used))
        latents[:, n_used:] = extra - extra.mean(axis=0)
        latents, _, _ = normalise_spread(latents)
    return latents


def pca_latents(data: TrainingData, latent_dim: int, rng: np.random.Generator) -> FloatArray:
    """The principal-component start (docs/method.md, M2) of the object profiles.

    The L × (R·dy) matrix of :func:`object_profiles` is centred over objects and its leading
    ``ds`` principal component scores are the latents. The centred matrix has rank ≤ L - 1:
    latent dimensions beyond its rank (e.g. ds ≥ L - 1, or objects whose smoothed responses
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
    matrix = object_profiles(data)
    matrix = matrix - matrix.mean(axis=0)
    u, singular, _ = np.linalg.svd(matrix, full_matrices=False)
    if singular.size == 0 or singular[0] <= 0 or not np.all(np.isfinite(singular)):
        return random_latents(n_objects, latent_dim, rng)
    present = singular > _RANK_TOLERANCE * singular[0]
    scores = np.zeros((n_objects, latent_dim))
    n_used = min(latent_dim, int(np.sum(present)))
    scores[:, :n_used] = u[:, :n_used] * singular[:n_used]
    return _latents_from_scores(scores, n_used, latent_dim, rng)


def _pairwise_distances(points: FloatArray) -> FloatArray:
    """Euclidean distances between the rows of ``points`` (n, d). Shape (n, n)."""
    return np.asarray(scipy.spatial.distance.cdist(points, points), dtype=np.float64)


def _geodesic_distances(distances: FloatArray, k: int) -> FloatArray | None:
    """Shortest-path distances along the symmetric k-nearest-neighbour graph, or ``None``
    when the graph is not connected."""
    n = distances.shape[0]
    order = np.argsort(distances, axis=1, kind="stable")[:, 1 : k + 1]
    rows = np.repeat(np.arange(n), k)
    graph = np.zeros_like(distances)
    graph[rows, order.ravel()] = distances[rows, order.ravel()]
    graph = np.maximum(graph, graph.T)
    n_components, _ = scipy.sparse.csgraph.connected_components(graph, directed=False)
    if n_components > 1:
        return None
    return np.asarray(scipy.sparse.csgraph.shortest_path(graph, directed=False))


def _classical_mds(distances: FloatArray, latent_dim: int) -> tuple[FloatArray, int]:
    """Classical MDS: the leading eigenvectors of the double-centred -½ D² scaled by the
    square roots of their eigenvalues. Returns (scores (L, latent_dim), dimensions present)."""
    n = distances.shape[0]
    sq = distances**2
    gram = -0.5 * (sq - sq.mean(axis=0) - sq.mean(axis=1)[:, None] + sq.mean())
    values, vectors = np.linalg.eigh(gram)
    values, vectors = values[::-1], vectors[:, ::-1]
    present = values > _RANK_TOLERANCE * max(float(values[0]), 1e-300)
    n_used = min(latent_dim, int(np.sum(present)), n - 1)
    scores = np.zeros((n, latent_dim))
    scores[:, :n_used] = vectors[:, :n_used] * np.sqrt(values[:n_used])
    return scores, n_used


def isomap_latents(
    data: TrainingData,
    latent_dim: int,
    rng: np.random.Generator,
    neighbours: tuple[int, ...] = ISOMAP_NEIGHBOURS,
) -> FloatArray:
    """The Isomap start: classical MDS of geodesic distances between the object profiles.

    For every k in ``neighbours`` (capped at L - 1) whose symmetric k-nearest-neighbour graph
    of the :func:`object_profiles` is connected, the shortest-path distances are embedded in
    ``ds`` dimensions by classical MDS; the k with the lowest residual variance
    1 - corr²(geodesic distances, embedded distances) wins. Missing dimensions are filled as
    in :func:`pca_latents`; when no graph is connected (or every profile coincides) the start
    is :func:`pca_latents`.

    Args:
        data: Training touches.
        latent_dim: ds ≥ 1.
        rng: Random generator (used only for degenerate dimensions).
        neighbours: Neighbour counts k to try (each ≥ 1).

    Returns:
        Normalised latents (centred, unit RMS spread). Shape (L, ds).
    """
    if not neighbours or any(int(k) < 1 for k in neighbours):
        raise InvalidInputError(f"neighbours: need counts ≥ 1, received {neighbours!r}.")
    n_objects = data.n_objects
    distances = _pairwise_distances(object_profiles(data))
    if not np.all(np.isfinite(distances)) or not np.any(distances > 0):
        return pca_latents(data, latent_dim, rng)
    upper = np.triu_indices(n_objects, 1)
    best: tuple[float, FloatArray, int] | None = None
    for k in sorted({min(int(k), n_objects - 1) for k in neighbours}):
        geodesic = _geodesic_distances(distances, k)
        if geodesic is None:
            continue
        scores, n_used = _classical_mds(geodesic, latent_dim)
        if n_used == 0:
            continue
        embedded = _pairwise_distances(scores[:, :n_used])
        corr = np.corrcoef(geodesic[upper], embedded[upper])[0, 1]
        residual = 1.0 - float(corr) ** 2 if np.isfinite(corr) else np.inf
        if best is None or residual < best[0]:
            best = (residual, scores, n_used)
    if best is None:
        return pca_latents(data, latent_dim, rng)
    _, scores, n_used = best
    return _latents_from_scores(scores, n_used, latent_dim, rng)


def data_driven_starts(
    data: TrainingData, latent_dim: int, rng: np.random.Generator
) -> list[FloatArray]:
    """The data-driven starts of a fit: :func:`pca_latents` alone below
    :data:`ISOMAP_MIN_OBJECTS` objects; from there on :func:`isomap_latents` first, then
    :func:`pca_latents` (unless the Isomap start fell back to it).

    Neither wins everywhere: on Experiment-2-like worlds the fit from Isomap reached 11,400
    nats more at L = 100 × M = 100 (shared design), the fit from PCA ~100 nats more at
    L = 30 × M = 20 (random design: 20 random touches per object make the smoothed profiles,
    and so the neighbour graph, noisy). Each of shape (L, ds), normalised.
    """
    pca = pca_latents(data, latent_dim, rng)
    if data.n_objects < ISOMAP_MIN_OBJECTS:
        return [pca]
    isomap = isomap_latents(data, latent_dim, rng)
    if np.array_equal(isomap, pca):
        return [pca]
    return [isomap, pca]
