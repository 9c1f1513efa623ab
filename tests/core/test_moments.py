"""Moment matching (M3), mutual information (M4), update (M5) and the MI gradient.

Tolerances: structured vs the direct appendix formula 1e-9 relative (to the largest entry of the
reference); Monte Carlo within 5 standard errors (batch means); Gaussian conditioning 1e-10;
gradient vs central finite differences (step 1e-6) 1e-5 relative.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.gp.posterior import condition, predict
from core.recognition.information_gradient import mutual_information_and_gradient
from core.recognition.moments import (
    action_statistics,
    mutual_information,
    predictive_moments,
    update_belief,
)
from core.types import GaussianBelief, Hyperparameters, ManifoldModel, TrainingData
from tests.core.agreement import assert_moments_match_direct


def small_model(
    seed: int = 0,
    n_objects: int = 3,
    touches_per_object: int = 8,
    latent_dim: int = 2,
    action_dim: int = 2,
    observation_dim: int = 3,
    noise_variance: float = 0.05,
) -> ManifoldModel:
    """A small random model with touches of an object NOT contiguous (shuffled order)."""
    rng = np.random.default_rng(seed)
    n = n_objects * touches_per_object
    latents = rng.standard_normal((n_objects, latent_dim))
    object_index = rng.permutation(np.repeat(np.arange(n_objects), touches_per_object))
    actions = rng.standard_normal((n, action_dim))
    mixing_x = rng.standard_normal((action_dim, observation_dim))
    mixing_s = rng.standard_normal((latent_dim, observation_dim))
    observations = (
        np.sin(actions @ mixing_x + latents[object_index] @ mixing_s)
        + 2.0
        + 0.1 * rng.standard_normal((n, observation_dim))
    )
    data = TrainingData(
        object_names=tuple(f"obj{i}" for i in range(n_objects)),
        object_index=object_index,
        actions=actions,
        observations=observations,
    )
    hyper = Hyperparameters(
        signal_variance=rng.uniform(0.5, 2.0, observation_dim),
        noise_variance=np.full(observation_dim, noise_variance),
        latent_lengthscales=rng.uniform(0.6, 2.0, (observation_dim, latent_dim)),
        action_lengthscales=rng.uniform(0.6, 2.0, (observation_dim, action_dim)),
    )
    return condition(data, latents, hyper)


BELIEFS = {
    "broad": GaussianBelief(mean=np.array([0.1, -0.2]), cov=5.0 * np.eye(2)),
    "correlated": GaussianBelief(mean=np.array([0.4, 0.3]), cov=np.array([[0.5, 0.2], [0.2, 0.3]])),
    "narrow": GaussianBelief(mean=np.array([-0.7, 0.9]), cov=np.diag([0.01, 0.04])),
}


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return small_model()


@pytest.fixture(scope="module")
def actions() -> np.ndarray:
    return np.random.default_rng(1).normal(0.0, 0.8, (6, 2))


@pytest.mark.parametrize("belief_name", sorted(BELIEFS))
def test_structured_batched_moments_match_the_direct_appendix_formula(
    model: ManifoldModel, actions: np.ndarray, belief_name: str
) -> None:
    belief = BELIEFS[belief_name]
    _, information = assert_moments_match_direct(model, belief, actions)
    assert np.all(information > 0)


def test_direct_formula_agreement_also_holds_with_a_one_dimensional_latent() -> None:
    model = small_model(seed=3, n_objects=4, latent_dim=1, action_dim=1, observation_dim=2)
    belief = GaussianBelief(mean=np.array([0.3]), cov=np.array([[2.0]]))
    actions = np.linspace(-2.0, 2.0, 5)[:, None]
    assert_moments_match_direct(model, belief, actions)


def _batch_mean_estimates(
    latents: np.ndarray, observations: np.ndarray, n_batches: int
) -> tuple[np.ndarray, np.ndarray]:
    """Estimates of [E y, Cov y, Cov(s, y)] flattened, and their standard errors."""

    def estimate(s: np.ndarray, y: np.ndarray) -> np.ndarray:
        s_c = s - s.mean(axis=0)
        y_c = y - y.mean(axis=0)
        return np.concatenate(
            [y.mean(axis=0), (y_c.T @ y_c / len(y)).ravel(), (s_c.T @ y_c / len(y)).ravel()]
        )

    batches = np.array(
        [
            estimate(s, y)
            for s, y in zip(
                np.array_split(latents, n_batches),
                np.array_split(observations, n_batches),
                strict=True,
            )
        ]
    )
    return estimate(latents, observations), batches.std(axis=0, ddof=1) / np.sqrt(n_batches)


@pytest.mark.parametrize("belief_name", ["correlated", "broad"])
def test_moments_match_monte_carlo_of_y_given_s(model: ManifoldModel, belief_name: str) -> None:
    """Sample s ~ N(μ, Σ), then y | s from the GP predictive (noise included)."""
    belief = BELIEFS[belief_name]
    rng = np.random.default_rng(7)
    n_samples = 100_000
    action = np.array([0.3, -0.4])
    latents = rng.multivariate_normal(belief.mean, belief.cov, n_samples)
    mean, variance = predict(model, latents, np.tile(action, (n_samples, 1)))
    observations = mean + np.sqrt(variance) * rng.standard_normal(mean.shape)
    estimate, standard_error = _batch_mean_estimates(latents, observations, n_batches=40)

    moments = predictive_moments(model, belief, action_statistics(model, action[None, :]))
    analytic = np.concatenate(
        [moments.mean[0], moments.cov[0].ravel(), moments.cross_cov[0].ravel()]
    )
    assert np.all(np.abs(estimate - analytic) <= 5.0 * standard_error + 1e-12)
    # The check can fail: leaving the noise out of S is detected.
    dy = moments.mean.shape[1]
    noise_free = moments.cov[0] - np.diag(model.hyperparameters.noise_variance)
    diagonal = np.arange(dy) * (dy + 1) + dy
    gap = np.abs(estimate[diagonal] - np.diag(noise_free))
    assert np.all(gap > 5.0 * standard_error[diagonal])


@pytest.mark.parametrize("belief_name", sorted(BELIEFS))
def test_update_equals_gaussian_conditioning_of_the_matched_joint(
    model: ManifoldModel, actions: np.ndarray, belief_name: str
) -> None:
    belief = BELIEFS[belief_name]
    moments = predictive_moments(model, belief, action_statistics(model, actions))
    y = moments.mean[2] + np.array([0.3, -0.2, 0.5])
    updated = update_belief(belief, moments, 2, y)
    # Condition [[Σ, C], [Cᵀ, S]] through the joint precision matrix (a different route).
    cross = moments.cross_cov[2]
    joint = np.block([[belief.cov, cross], [cross.T, moments.cov[2]]])
    precision = np.linalg.inv(joint)
    ds = belief.dim
    cov = np.linalg.inv(precision[:ds, :ds])
    mean = belief.mean - cov @ precision[:ds, ds:] @ (y - moments.mean[2])
    np.testing.assert_allclose(updated.mean, mean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(updated.cov, cov, rtol=1e-9, atol=1e-12)
    assert np.linalg.det(updated.cov) < np.linalg.det(belief.cov)


def test_action_statistics_reused_across_beliefs_give_identical_moments(
    model: ManifoldModel, actions: np.ndarray
) -> None:
    shared = action_statistics(model, actions)
    for belief in BELIEFS.values():
        reused = predictive_moments(model, belief, shared)
        fresh = predictive_moments(model, belief, action_statistics(model, actions))
        np.testing.assert_array_equal(reused.mean, fresh.mean)
        np.testing.assert_array_equal(reused.cov, fresh.cov)
        np.testing.assert_array_equal(reused.cross_cov, fresh.cross_cov)
        # Batching over candidates does not change a candidate's moments.
        single = predictive_moments(model, belief, action_statistics(model, actions[3:4]))
        np.testing.assert_allclose(single.cov[0], reused.cov[3], rtol=1e-12, atol=1e-14)
        subset = predictive_moments(model, belief, shared.subset(np.array([3])))
        np.testing.assert_array_equal(subset.cov[0], reused.cov[3])


@pytest.mark.parametrize("belief_name", sorted(BELIEFS))
def test_mutual_information_gradient_matches_finite_differences(
    model: ManifoldModel, actions: np.ndarray, belief_name: str
) -> None:
    belief = BELIEFS[belief_name]
    batched = mutual_information(
        predictive_moments(model, belief, action_statistics(model, actions)), belief
    )
    step = 1e-6
    for index, action in enumerate(actions[:4]):
        value, gradient = mutual_information_and_gradient(model, belief, action)
        assert value == pytest.approx(batched[index], rel=1e-10)
        numeric = np.array(
            [
                (
                    mutual_information_and_gradient(model, belief, action + step * unit)[0]
                    - mutual_information_and_gradient(model, belief, action - step * unit)[0]
                )
                / (2 * step)
                for unit in np.eye(action.shape[0])
            ]
        )
        np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-8)


def test_mutual_information_vanishes_far_from_the_data(model: ManifoldModel) -> None:
    belief = BELIEFS["broad"]
    far = np.array([[60.0, -60.0], [0.3, 0.1]])
    information = mutual_information(
        predictive_moments(model, belief, action_statistics(model, far)), belief
    )
    assert information[0] < 1e-12
    assert information[1] > 1e-3


def test_bad_input_is_rejected_with_the_argument_named(model: ManifoldModel) -> None:
    belief = BELIEFS["broad"]
    with pytest.raises(InvalidInputError, match="actions"):
        action_statistics(model, np.zeros((3, 5)))
    with pytest.raises(InvalidInputError, match="actions"):
        action_statistics(model, np.array([[0.0, np.nan]]))
    with pytest.raises(InvalidInputError, match="actions"):
        action_statistics(model, np.zeros(2))
    stats = action_statistics(model, np.zeros((2, 2)))
    moments = predictive_moments(model, belief, stats)
    with pytest.raises(InvalidInputError, match="observation"):
        update_belief(belief, moments, 0, np.zeros(2))
    with pytest.raises(InvalidInputError, match="observation"):
        update_belief(belief, moments, 0, np.array([0.0, np.inf, 1.0]))
    with pytest.raises(InvalidInputError, match="index"):
        update_belief(belief, moments, 2, np.zeros(3))
    wrong_dim = GaussianBelief(mean=np.zeros(3), cov=np.eye(3))
    with pytest.raises(InvalidInputError, match="belief"):
        predictive_moments(model, wrong_dim, stats)
    with pytest.raises(InvalidInputError, match="action"):
        mutual_information_and_gradient(model, belief, np.array([0.0, np.nan]))
    other = small_model(seed=5, observation_dim=2)
    with pytest.raises(InvalidInputError, match="stats"):
        predictive_moments(other, belief, stats)
