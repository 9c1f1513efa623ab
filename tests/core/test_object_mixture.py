"""The belief over the learned objects (a Gaussian mixture) and its predictive moments.

Tolerances: one component against (M3) directly 1e-12 relative; Monte Carlo within 5 standard
errors (batch means, as in test_moments.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.gp.posterior import predict
from core.recognition.moments import action_statistics, mutual_information, predictive_moments
from core.recognition.object_mixture import (
    WEIGHT_FLOOR,
    ObjectMixture,
    component_terms,
    mixture_information,
    mixture_moments,
)
from core.recognition.planning import ActivePolicy, Planner
from core.recognition.session import (
    OBJECT_COMPONENT_VARIANCE,
    RecognitionSession,
    RecognitionSettings,
    default_prior,
    objects_belief,
)
from core.types import GaussianBelief, ManifoldModel
from tests.core.test_moments import _batch_mean_estimates, small_model


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return small_model(seed=2, n_objects=4)


def _flat(moments: object, index: int = 0) -> np.ndarray:
    return np.concatenate(
        [
            moments.mean[index],  # type: ignore[attr-defined]
            moments.cov[index].ravel(),  # type: ignore[attr-defined]
            moments.cross_cov[index].ravel(),  # type: ignore[attr-defined]
        ]
    )


def test_one_component_is_the_gaussian_of_that_object(model: ManifoldModel) -> None:
    actions = np.random.default_rng(0).normal(0.0, 0.8, (5, 2))
    stats = action_statistics(model, actions)
    cov = np.array([[0.07, 0.01], [0.01, 0.04]])
    weights = np.array([0.0, 0.0, 1.0, 0.0])
    mixture = ObjectMixture(model.latents, weights, cov)
    gaussian = GaussianBelief(mean=model.latents[2], cov=cov)
    direct = predictive_moments(model, gaussian, stats)
    mixed = mixture_moments(model, mixture, stats)
    for got, want in [
        (mixed.mean, direct.mean),
        (mixed.cov, direct.cov),
        (mixed.cross_cov, direct.cross_cov),
    ]:
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(
        mixture_information(model, mixture, stats),
        mutual_information(direct, gaussian),
        rtol=1e-10,
    )


def test_moments_match_monte_carlo_of_the_mixture(model: ManifoldModel) -> None:
    """Draw l ~ p, s ~ N(s_l, c·I), then y | s from the GP predictive (noise included)."""
    rng = np.random.default_rng(11)
    weights = np.array([0.1, 0.4, 0.2, 0.3])
    cov = 0.05 * np.eye(2)
    mixture = ObjectMixture(model.latents, weights, cov)
    n_samples = 100_000
    action = np.array([0.2, -0.5])
    which = rng.choice(4, size=n_samples, p=weights)
    latents = model.latents[which] + rng.multivariate_normal(np.zeros(2), cov, n_samples)
    mean, variance = predict(model, latents, np.tile(action, (n_samples, 1)))
    observations = mean + np.sqrt(variance) * rng.standard_normal(mean.shape)
    estimate, standard_error = _batch_mean_estimates(latents, observations, n_batches=40)

    moments = mixture_moments(model, mixture, action_statistics(model, action[None, :]))
    analytic = _flat(moments)
    assert np.all(np.abs(estimate - analytic) <= 5.0 * standard_error + 1e-12)
    # The check can fail: the spread of the objects' means between components is detected.
    dy = moments.mean.shape[1]
    within = sum(
        w
        * predictive_moments(
            model,
            GaussianBelief(mean=s, cov=cov),
            action_statistics(model, action[None, :]),
        ).cov[0]
        for w, s in zip(weights, model.latents, strict=True)
    )
    diagonal = np.arange(dy) * (dy + 1) + dy
    gap = np.abs(estimate[diagonal] - np.diag(within))
    assert np.any(gap > 5.0 * standard_error[diagonal])


def test_negligible_components_are_left_out(model: ManifoldModel) -> None:
    stats = action_statistics(model, np.random.default_rng(1).normal(0.0, 0.8, (4, 2)))
    cov = 0.05 * np.eye(2)
    tiny = 0.1 * WEIGHT_FLOOR
    with_tiny = ObjectMixture(model.latents, np.array([0.5 - tiny, tiny, 0.25, 0.25]), cov)
    without = ObjectMixture(model.latents, np.array([0.5, 0.0, 0.25, 0.25]), cov)
    np.testing.assert_allclose(
        mixture_information(model, with_tiny, stats),
        mixture_information(model, without, stats),
        rtol=1e-8,
    )


def test_kept_component_terms_give_the_same_moments_and_are_reused(model: ManifoldModel) -> None:
    stats = action_statistics(model, np.random.default_rng(3).normal(0.0, 0.8, (5, 2)))
    mixture = objects_belief(model, np.array([0.4, 0.3, 0.2, 0.1]))
    terms = component_terms(model, mixture)
    direct, kept = (
        mixture_moments(model, mixture, stats),
        mixture_moments(model, mixture, stats, terms),
    )
    for field in ("mean", "cov", "cross_cov"):
        np.testing.assert_array_equal(getattr(kept, field), getattr(direct, field))
    with pytest.raises(InvalidInputError, match="terms: expected one per component"):
        mixture_moments(model, mixture, stats, terms[:2])
    # A planner keeps them for a trial's mixtures, which differ only in their weights ...
    planner = Planner(model, ActivePolicy())
    first = planner.mixture_terms(mixture)
    again = planner.mixture_terms(objects_belief(model, np.array([0.1, 0.2, 0.3, 0.4])))
    assert again is first
    # ... and computes them afresh for other components.
    moved = ObjectMixture(model.latents + 0.1, mixture.weights, mixture.cov)
    assert planner.mixture_terms(moved) is not first
    np.testing.assert_array_equal(
        planner.mutual_information(mixture, stats.actions),
        mixture_information(model, mixture, stats),
    )


def test_the_moment_matched_gaussian_has_the_mixtures_moments(model: ManifoldModel) -> None:
    weights = np.array([0.1, 0.4, 0.2, 0.3])
    cov = np.array([[0.05, 0.01], [0.01, 0.03]])
    matched = ObjectMixture(model.latents, weights, cov).moment_matched()
    centre = weights @ model.latents
    np.testing.assert_allclose(matched.mean, centre)
    spread = model.latents - centre
    expected = cov + sum(w * np.outer(d, d) for w, d in zip(weights, spread, strict=True))
    np.testing.assert_allclose(matched.cov, expected, rtol=1e-12)


@pytest.mark.parametrize(
    ("weights", "cov", "message"),
    [
        (np.array([0.5, 0.5, 0.5, -0.5]), np.eye(2), "mixture weights"),
        (np.array([0.3, 0.3, 0.3, 0.3]), np.eye(2), "sum to 1"),
        (np.full(3, 1 / 3), np.eye(2), "mixture weights"),
        (np.full(4, 0.25), np.array([[1.0, 2.0], [2.0, 1.0]]), "positive definite"),
        (np.full(4, 0.25), np.eye(3), "mixture cov"),
    ],
)
def test_bad_mixtures_are_refused_naming_the_field(
    model: ManifoldModel, weights: np.ndarray, cov: np.ndarray, message: str
) -> None:
    with pytest.raises(InvalidInputError, match=message):
        ObjectMixture(model.latents, weights, cov)


def test_a_mixture_of_another_dimension_is_refused(model: ManifoldModel) -> None:
    mixture = ObjectMixture(np.zeros((4, 3)), np.full(4, 0.25), np.eye(3))
    stats = action_statistics(model, np.zeros((1, 2)))
    with pytest.raises(InvalidInputError, match="ds=3"):
        mixture_moments(model, mixture, stats)


def _session(model: ManifoldModel, plan_under: str) -> RecognitionSession:
    planner = Planner(model, ActivePolicy(), n_candidates=64)
    settings = RecognitionSettings(max_steps=3, tolerance=0.0, plan_under=plan_under)  # type: ignore[arg-type]
    return RecognitionSession(model, planner, default_prior(model), settings)


def test_the_active_policy_plans_under_the_objects_by_default(model: ManifoldModel) -> None:
    session = _session(model, "objects")
    rng = np.random.default_rng(3)
    world = np.random.default_rng(4)
    for _ in range(3):
        belief = session.planning_belief()
        assert isinstance(belief, ObjectMixture)
        np.testing.assert_array_equal(belief.weights, session.probabilities)
        np.testing.assert_allclose(belief.cov, OBJECT_COMPONENT_VARIANCE * np.eye(2))
        stats = session.planner.candidate_statistics
        scores = mixture_information(model, belief, stats)
        planned = session.suggest(rng)
        np.testing.assert_array_equal(planned.action, stats.actions[int(np.argmax(scores))])
        step = session.observe(planned.action, 2.0 + 0.3 * world.standard_normal(3))
        assert step.mutual_information == pytest.approx(float(scores.max()), rel=1e-12)
    # Before any touch the belief is the objects equally likely.
    np.testing.assert_allclose(objects_belief(model).weights, np.full(4, 0.25))


def test_the_papers_planning_is_under_the_gaussian(model: ManifoldModel) -> None:
    session = _session(model, "gaussian")
    belief = session.planning_belief()
    assert isinstance(belief, GaussianBelief)
    planned = session.suggest(np.random.default_rng(3))
    # The objects' mixture chooses differently on this model: the check can fail.
    other = _session(model, "objects").suggest(np.random.default_rng(3))
    assert not np.array_equal(planned.action, other.action)


def test_an_unknown_planning_belief_is_refused() -> None:
    with pytest.raises(InvalidInputError, match="plan_under"):
        RecognitionSettings(plan_under="mixture")  # type: ignore[arg-type]
