"""The sparse variational (inducing-point) path: a lower bound on the exact likelihood that
becomes exact when every touch is an inducing point, with a correct analytic gradient."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from core.gp.likelihood import ManifoldLikelihood
from core.gp.manifold import FitOptions, fit_manifold
from core.gp.posterior import AUTO_SPARSE_ABOVE, condition, predict, resolve_structure
from core.gp.sparse import SparseLikelihood, condition_sparse, select_inducing_points
from core.recognition.information_gradient import mutual_information_and_gradient
from core.recognition.moments import action_statistics, mutual_information, predictive_moments
from core.types import GaussianBelief, Hyperparameters, TrainingData
from tests.core.finite_differences import central_differences


def make_problem(
    seed: int, n_objects: int = 3, touches: int = 12
) -> tuple[TrainingData, np.ndarray, Hyperparameters]:
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(rng, n_objects=n_objects, action_dim=2, observation_dim=3)
    data = sample_dataset(world, rng, touches)
    latents = rng.standard_normal((n_objects, 2))
    hyper = Hyperparameters(
        signal_variance=rng.uniform(0.5, 1.5, 3),
        noise_variance=rng.uniform(0.01, 0.05, 3),
        latent_lengthscales=rng.uniform(0.7, 2.0, (3, 2)),
        action_lengthscales=rng.uniform(0.8, 2.0, (3, 2)),
    )
    return data, latents, hyper


def test_every_touch_as_inducing_point_gives_the_exact_likelihood() -> None:
    data, latents, hyper = make_problem(0)
    exact = ManifoldLikelihood(data, 2)
    sparse = SparseLikelihood(data, 2, n_inducing=data.n_touches, jitter=1e-10)
    vector = exact.layout.pack(latents, hyper)
    assert sparse.inducing.size == data.n_touches
    value_e, grad_e = exact.value_and_gradient(vector)
    value_s, grad_s = sparse.value_and_gradient(vector)
    assert value_s == pytest.approx(value_e, rel=1e-7)
    np.testing.assert_allclose(grad_s, grad_e, rtol=1e-5, atol=1e-5 * np.abs(grad_e).max())


@pytest.mark.parametrize("n_inducing", [4, 9, 20])
def test_bound_is_below_the_exact_log_likelihood_and_gradient_is_exact(n_inducing: int) -> None:
    data, latents, hyper = make_problem(1)
    exact = ManifoldLikelihood(data, 2)
    sparse = SparseLikelihood(data, 2, n_inducing=n_inducing)
    vector = exact.layout.pack(latents, hyper)
    value, grad = sparse.value_and_gradient(vector)
    assert value > exact.value(vector)  # -F ≥ -log p
    numeric = central_differences(sparse.value, vector)
    np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max())


def test_more_inducing_points_tighten_the_bound() -> None:
    data, latents, hyper = make_problem(2)
    vector = ManifoldLikelihood(data, 2).layout.pack(latents, hyper)
    values = [
        SparseLikelihood(data, 2, n_inducing=m, jitter=1e-8).value(vector) for m in (3, 6, 12, 24)
    ]
    # Nested inducing sets: the bound can only rise (-F fall), up to the jitter.
    assert all(b <= a + 1e-6 * abs(a) for a, b in itertools.pairwise(values))
    assert values[-1] < values[0]


def test_inducing_points_are_deterministic_nested_and_spread_over_objects() -> None:
    data, _, _ = make_problem(3, n_objects=4, touches=10)
    small = select_inducing_points(data, 8)
    again = select_inducing_points(data, 8)
    np.testing.assert_array_equal(small.touch_index, again.touch_index)
    assert np.bincount(small.object_index, minlength=4).tolist() == [2, 2, 2, 2]
    larger = select_inducing_points(data, 12)
    assert set(small.touch_index.tolist()) <= set(larger.touch_index.tolist())
    np.testing.assert_array_equal(larger.actions, data.actions[larger.touch_index])
    fewer_than_objects = select_inducing_points(data, 2)
    assert fewer_than_objects.size == 2
    assert len(set(fewer_than_objects.object_index.tolist())) == 2
    assert select_inducing_points(data, 10_000).size == data.n_touches


def test_sparse_posterior_predicts_like_the_dense_one_with_every_touch() -> None:
    data, latents, hyper = make_problem(4)
    dense = condition(data, latents, hyper, structure="dense")
    sparse = condition_sparse(data, latents, hyper, n_inducing=data.n_touches, jitter=1e-10)
    assert sparse.posterior.structure == "sparse"
    assert sparse.posterior.beta.shape == (3, data.n_touches)
    assert sparse.log_likelihood == pytest.approx(dense.log_likelihood, rel=1e-7)
    rng = np.random.default_rng(5)
    queries, actions = rng.standard_normal((6, 2)), rng.standard_normal((6, 2))
    mean_d, var_d = predict(dense, queries, actions)
    mean_s, var_s = predict(sparse, queries, actions)
    np.testing.assert_allclose(mean_s, mean_d, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(var_s, var_d, rtol=1e-6, atol=1e-7)


def test_sparse_predictive_approaches_the_exact_one_as_inducing_points_are_added() -> None:
    data, latents, hyper = make_problem(6)
    dense = condition(data, latents, hyper, structure="dense")
    rng = np.random.default_rng(7)
    queries = latents[rng.integers(3, size=20)]
    actions = rng.standard_normal((20, 2))
    mean_d, var_d = predict(dense, queries, actions)
    errors = []
    for m in (6, 24, data.n_touches):
        sparse = condition(data, latents, hyper, structure="sparse", n_inducing=m)
        assert sparse.posterior.inducing is not None
        assert sparse.posterior.beta.shape == (3, m)
        assert sparse.log_likelihood <= dense.log_likelihood + 1e-6
        mean_s, var_s = predict(sparse, queries, actions)
        errors.append((np.sqrt(np.mean((mean_s - mean_d) ** 2)), np.mean(var_s - var_d)))
    assert errors[0][0] > errors[1][0] > errors[2][0]
    assert errors[0][1] > errors[1][1] > 0  # the sparse posterior is less certain on average
    assert errors[2][0] < 1e-4


def test_auto_structure_goes_sparse_only_for_large_random_designs() -> None:
    data, _, _ = make_problem(8)
    assert resolve_structure(data)[0] == "dense"
    assert resolve_structure(data, "sparse")[0] == "sparse"
    big, _, _ = make_problem(9, n_objects=2, touches=AUTO_SPARSE_ABOVE // 2 + 1)
    assert resolve_structure(big)[0] == "sparse"
    with pytest.raises(InvalidInputError, match="structure: expected one of"):
        resolve_structure(data, "banded")  # type: ignore[arg-type]


def test_bad_settings_are_rejected() -> None:
    data, _, _ = make_problem(10)
    with pytest.raises(InvalidInputError, match="n_inducing"):
        select_inducing_points(data, 0)
    with pytest.raises(InvalidInputError, match="jitter"):
        SparseLikelihood(data, 2, jitter=0.0)
    with pytest.raises(InvalidInputError, match="latent_dim"):
        SparseLikelihood(data, 0)


def test_moments_and_gradient_run_on_the_inducing_points() -> None:
    data, latents, hyper = make_problem(11)
    dense = condition(data, latents, hyper, structure="dense")
    full = condition_sparse(data, latents, hyper, n_inducing=data.n_touches, jitter=1e-10)
    belief = GaussianBelief(mean=latents.mean(axis=0), cov=np.diag([1.0, 0.6]))
    candidates = np.random.default_rng(12).standard_normal((5, 2))
    mi_dense = mutual_information(
        predictive_moments(dense, belief, action_statistics(dense, candidates)), belief
    )
    mi_full = mutual_information(
        predictive_moments(full, belief, action_statistics(full, candidates)), belief
    )
    np.testing.assert_allclose(mi_full, mi_dense, rtol=1e-5)
    value_d, grad_d = mutual_information_and_gradient(dense, belief, candidates[1])
    value_f, grad_f = mutual_information_and_gradient(full, belief, candidates[1])
    assert value_f == pytest.approx(value_d, rel=1e-5)
    np.testing.assert_allclose(grad_f, grad_d, rtol=1e-4, atol=1e-6)
    # With few inducing points (some objects have none) everything still runs.
    small = condition(data, latents, hyper, structure="sparse", n_inducing=2)
    stats = action_statistics(small, candidates)
    assert stats.trace_blocks.shape == (5, 3, 3, 3)
    mi_small = mutual_information(predictive_moments(small, belief, stats), belief)
    assert np.all(np.isfinite(mi_small))
    assert np.all(mi_small >= 0)


@pytest.mark.parametrize("structure", ["dense", "sparse"])
def test_many_objects_use_per_object_sums_with_the_same_moments_and_gradient(
    structure: str,
) -> None:
    data, _, _ = make_problem(13, n_objects=12, touches=6)
    rng = np.random.default_rng(14)
    latents = rng.standard_normal((12, 2))
    hyper = Hyperparameters(
        signal_variance=np.ones(3),
        noise_variance=np.full(3, 0.02),
        latent_lengthscales=np.full((3, 2), 1.2),
        action_lengthscales=np.full((3, 2), 1.5),
    )
    model = condition(data, latents, hyper, structure=structure, n_inducing=40)  # type: ignore[arg-type]
    belief = GaussianBelief(mean=latents[3] + 0.1, cov=np.diag([0.5, 0.3]))
    x = rng.standard_normal(2)
    stats = action_statistics(model, x[None, :])
    value, gradient = mutual_information_and_gradient(model, belief, x)
    assert value == pytest.approx(
        float(mutual_information(predictive_moments(model, belief, stats), belief)[0]), rel=1e-10
    )
    numeric = central_differences(
        lambda point: mutual_information_and_gradient(model, belief, point)[0], x
    )
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-8)


def test_a_sparse_fit_conditions_a_sparse_model_on_the_same_inducing_points() -> None:
    data, _, _ = make_problem(15, n_objects=3, touches=20)
    options = FitOptions(restarts=0, structure="sparse", n_inducing=15, max_iterations=100)
    model = fit_manifold(data, 2, np.random.default_rng(16), options)
    assert model.posterior.structure == "sparse"
    assert model.posterior.inducing is not None
    np.testing.assert_array_equal(
        model.posterior.inducing.touch_index, select_inducing_points(data, 15).touch_index
    )
    exact = condition(data, model.latents, model.hyperparameters, structure="dense")
    assert model.log_likelihood < exact.log_likelihood
