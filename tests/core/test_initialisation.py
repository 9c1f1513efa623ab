"""Data-driven starts (core.gp.initialisation): PCA, Isomap and the choice between them."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.designs import collect, shared_design
from core.evaluation.metrics import procrustes_r2
from core.evaluation.worlds import random_experiment2_world, sample_experiment1
from core.gp.initialisation import (
    ISOMAP_MIN_OBJECTS,
    _geodesic_distances,
    _pairwise_distances,
    data_driven_starts,
    isomap_latents,
    normalise_spread,
    object_profiles,
    pca_latents,
)
from core.types import TrainingData


def curved_world_data(n_objects: int, seed: int = 0) -> tuple[TrainingData, np.ndarray]:
    """An Experiment-2-like world (ds = 2, dx = 6, dy = 5) touched with a shared design of
    40 actions; returns the data and the world's latents."""
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(rng, n_objects=n_objects)
    plan = shared_design(n_objects, 40, world.action_mean, world.action_cov, rng)
    return collect(world, plan, rng), world.latents


def assert_normalised(latents: np.ndarray) -> None:
    np.testing.assert_allclose(latents.mean(axis=0), 0.0, atol=1e-12)
    assert np.sqrt(np.mean(np.sum(latents**2, axis=1))) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_isomap_unfolds_what_pca_folds(seed: int) -> None:
    """With many objects on a curved 2-D manifold the PCA start folds it; the Isomap start
    is close to the true latents up to a similarity (Procrustes R²)."""
    data, truth = curved_world_data(60, seed)
    isomap = isomap_latents(data, 2, np.random.default_rng(0))
    pca = pca_latents(data, 2, np.random.default_rng(0))
    assert_normalised(isomap)
    r2_isomap, r2_pca = procrustes_r2(truth, isomap), procrustes_r2(truth, pca)
    assert r2_isomap > 0.8, (r2_isomap, r2_pca)
    assert r2_isomap > r2_pca + 0.2, (r2_isomap, r2_pca)


def test_isomap_of_the_complete_graph_is_pca() -> None:
    """k = L - 1: geodesic distances are the Euclidean ones and classical MDS of Euclidean
    distances gives the principal component scores (up to signs)."""
    data, _ = curved_world_data(12)
    isomap = isomap_latents(data, 2, np.random.default_rng(0), neighbours=(11,))
    pca = pca_latents(data, 2, np.random.default_rng(0))
    np.testing.assert_allclose(np.abs(isomap), np.abs(pca), atol=1e-8)


def test_a_disconnected_neighbour_graph_falls_back_to_pca() -> None:
    """The 1-nearest-neighbour graph of these 10 objects splits into components (checked
    below), so the start is the PCA one."""
    data, _ = curved_world_data(10)
    distances = _pairwise_distances(object_profiles(data))
    assert _geodesic_distances(distances, 1) is None
    isomap = isomap_latents(data, 2, np.random.default_rng(0), neighbours=(1,))
    np.testing.assert_array_equal(isomap, pca_latents(data, 2, np.random.default_rng(0)))


def test_few_objects_keep_the_pca_start() -> None:
    data = sample_experiment1(np.random.default_rng(0))
    assert data.n_objects < ISOMAP_MIN_OBJECTS
    (only,) = data_driven_starts(data, 1, np.random.default_rng(0))
    np.testing.assert_array_equal(only, pca_latents(data, 1, np.random.default_rng(0)))


def test_many_objects_start_from_isomap_and_pca() -> None:
    data, _ = curved_world_data(ISOMAP_MIN_OBJECTS + 4)
    isomap, pca = data_driven_starts(data, 2, np.random.default_rng(0))
    np.testing.assert_array_equal(isomap, isomap_latents(data, 2, np.random.default_rng(0)))
    np.testing.assert_array_equal(pca, pca_latents(data, 2, np.random.default_rng(0)))


def test_latent_dimensions_beyond_the_embedding_are_filled() -> None:
    """ds ≥ L - 1: the MDS has at most L - 1 dimensions; the rest get small random values and
    the start is still normalised with distinct columns."""
    data, _ = curved_world_data(9)
    latents = isomap_latents(data, 9, np.random.default_rng(0))
    assert latents.shape == (9, 9)
    assert_normalised(latents)
    assert np.linalg.matrix_rank(latents) >= 8


def test_identical_objects_give_a_valid_start() -> None:
    data, _ = curved_world_data(9)
    same = TrainingData(
        data.object_names, data.object_index, data.actions, np.zeros_like(data.observations)
    )
    latents = isomap_latents(same, 2, np.random.default_rng(0))
    normalised, _, _ = normalise_spread(latents)
    np.testing.assert_allclose(latents, normalised)
    assert np.all(np.isfinite(latents))


@pytest.mark.parametrize("neighbours", [(), (0,), (4, -1)])
def test_bad_neighbour_counts_are_named(neighbours: tuple[int, ...]) -> None:
    data, _ = curved_world_data(9)
    with pytest.raises(InvalidInputError, match="neighbours"):
        isomap_latents(data, 2, np.random.default_rng(0), neighbours=neighbours)
