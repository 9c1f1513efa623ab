"""The next touch given a trial's touches: the conditional against the joint trial likelihood, the
GP cross-covariance against its direct formula, and the planners that use it."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.worlds import Experiment1World
from core.gp.cross_covariance import object_cross_covariances
from core.gp.placement_effect import predictive_covariance, trial_log_likelihoods
from core.gp.posterior import predict_model_space
from core.recognition.trial_conditioning import TrialTouches, trial_corrections
from core.types import ManifoldModel


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return experiment1_at_true_latents(seed=0, touches_per_object=15)


def _trial(n: int, seed: int, target: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 1))
    y = Experiment1World().observe(target, x, rng)
    return x, y


def test_cross_covariance_is_the_predictive_covariance_between_the_two_sets(
    model: ManifoldModel,
) -> None:
    x, _ = _trial(3, 1)
    others = np.linspace(-2.0, 2.0, 5)[:, None]
    cross = object_cross_covariances(model, x, others)
    assert cross.shape == (model.latents.shape[0], 3, 3, 5)
    for obj in range(model.latents.shape[0]):
        joint = predictive_covariance(model, model.latents[obj], np.vstack([x, others]))
        np.testing.assert_allclose(cross[obj], joint[:, :3, 3:], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("fraction", [0.0, 0.6])
def test_conditional_is_the_joint_likelihood_chain_rule(
    model: ManifoldModel, fraction: float
) -> None:
    """log p(y_1..y_T+1 | l) − log p(y_1..y_T | l) is the conditional density of y_T+1."""
    x, y = _trial(5, 2)
    shared = fraction * model.hyperparameters.noise_variance
    past = TrialTouches(x[:4], y[:4], shared)
    corrections = trial_corrections(model, past, x[4:])
    n_objects = model.latents.shape[0]
    mean, variance = predict_model_space(model, model.latents, np.repeat(x[4:], n_objects, axis=0))
    conditional_mean = mean + corrections.shift[0]
    conditional_variance = corrections.conditional_variance(variance[None])[0]
    residual = model.to_model_space(y[4:])[0] - conditional_mean
    log_density = -0.5 * np.sum(
        np.log(2 * np.pi * conditional_variance) + residual**2 / conditional_variance, axis=1
    )
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    chain = trial_log_likelihoods(model, x, y, shared) - trial_log_likelihoods(
        model, x[:4], y[:4], shared
    )
    np.testing.assert_allclose(log_density + jacobian, chain, rtol=1e-8, atol=1e-8)


def test_a_repeated_action_under_a_shared_offset_is_mostly_known(model: ManifoldModel) -> None:
    """With most of the noise shared, the repeat of a touched action is predicted near what was
    seen under every object, and far less uncertain than before the touch."""
    x, y = _trial(1, 3)
    shared = 0.9 * model.hyperparameters.noise_variance
    corrections = trial_corrections(model, TrialTouches(x, y, shared), x)
    n_objects = model.latents.shape[0]
    mean, variance = predict_model_space(model, model.latents, np.repeat(x, n_objects, axis=0))
    conditional = corrections.conditional_variance(variance[None])[0]
    assert np.all(conditional < 0.2 * variance)
    spread_before = np.ptp(mean, axis=0)
    spread_after = np.ptp(mean + corrections.shift[0], axis=0)
    assert np.all(spread_after < 0.2 * spread_before)
    # Nothing shared: only the GP's own uncertainty at x is seen again, so less is known.
    fresh = trial_corrections(model, TrialTouches(x, y, 0.0 * shared), x)
    assert np.all(fresh.conditional_variance(variance[None])[0] > conditional)


def test_trial_touches_refuse_bad_input(model: ManifoldModel) -> None:
    x, y = _trial(2, 4)
    with pytest.raises(InvalidInputError, match="at least one touch"):
        TrialTouches(x[:0], y[:0], np.zeros(3))
    with pytest.raises(InvalidInputError, match="trial observations"):
        TrialTouches(x, y[:1], np.zeros(3))
    too_large = TrialTouches(x, y, model.hyperparameters.noise_variance)
    with pytest.raises(InvalidInputError):
        trial_corrections(model, too_large, x)
    wrong_dx = TrialTouches(np.hstack([x, x]), y, np.zeros(3))
    with pytest.raises(InvalidInputError, match="trial actions"):
        trial_corrections(model, wrong_dx, x)
