"""The joint trial likelihood (GP covariance and placement effect), σ_b²'s estimator, and their use
in recognition."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.stats

from core.errors import InvalidInputError
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.worlds import EXPERIMENT1_THETAS, Experiment1World, sample_experiment1
from core.gp.kernels import squared_exponential
from core.gp.placement_effect import (
    estimate_placement_variance,
    placement_groups,
    predictive_covariance,
    trial_log_likelihoods,
    with_placement_effect,
)
from core.gp.posterior import condition, predict_model_space
from core.recognition.object_posterior import (
    normalise_log_probabilities,
    object_log_likelihoods,
    object_posterior,
)
from core.recognition.planning import PassivePolicy, Planner
from core.recognition.session import RecognitionSession, RecognitionSettings
from core.types import Hyperparameters, ManifoldModel, TrainingData


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    return experiment1_at_true_latents(seed=0, touches_per_object=15)


def _trial(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 1))
    y = Experiment1World().observe(1, x, rng)
    return x, y


def test_one_touch_equals_the_independent_density(model: ManifoldModel) -> None:
    x, y = _trial(1, 1)
    independent = object_log_likelihoods(model, x, y, "independent")
    variance = 0.5 * model.hyperparameters.noise_variance
    joint = trial_log_likelihoods(model, x, y, variance)
    np.testing.assert_allclose(joint, independent, rtol=1e-10)
    np.testing.assert_allclose(object_log_likelihoods(model, x, y), independent, rtol=1e-10)


def test_joint_is_the_default_and_independent_is_the_product(model: ManifoldModel) -> None:
    x, y = _trial(6, 2)
    zero = np.zeros(3)
    np.testing.assert_array_equal(
        object_log_likelihoods(model, x, y), trial_log_likelihoods(model, x, y, zero)
    )
    per_touch = [object_log_likelihoods(model, x[t : t + 1], y[t : t + 1]) for t in range(6)]
    np.testing.assert_allclose(
        object_log_likelihoods(model, x, y, "independent"), np.sum(per_touch, axis=0), rtol=1e-12
    )
    assert not np.allclose(object_log_likelihoods(model, x, y), np.sum(per_touch, axis=0))
    with pytest.raises(InvalidInputError, match="trial_likelihood"):
        object_log_likelihoods(model, x, y, "product")  # type: ignore[arg-type]


def test_zero_placement_variance_keeps_the_posterior_exactly(model: ManifoldModel) -> None:
    x, y = _trial(6, 2)
    zero = dataclasses.replace(model, placement_variance=np.zeros(3))
    for setting in ("joint", "independent"):
        assert np.array_equal(
            object_posterior(zero, x, y, setting), object_posterior(model, x, y, setting)
        )


def test_placement_variance_only_when_the_touches_share_a_placement(
    model: ManifoldModel,
) -> None:
    x, y = _trial(4, 11)
    variance = 0.5 * model.hyperparameters.noise_variance
    placed = dataclasses.replace(model, placement_variance=variance)
    np.testing.assert_array_equal(
        object_log_likelihoods(placed, x, y), trial_log_likelihoods(model, x, y, variance)
    )
    np.testing.assert_array_equal(
        object_log_likelihoods(placed, x, y, shared_placement=False),
        object_log_likelihoods(model, x, y),
    )
    np.testing.assert_array_equal(
        object_log_likelihoods(placed, x, y, "independent"),
        object_log_likelihoods(model, x, y, "independent"),
    )


def test_predictive_covariance_diagonal_is_the_predictive_variance(model: ManifoldModel) -> None:
    x, _ = _trial(4, 3)
    cov = predictive_covariance(model, model.latents[2], x)
    _, variance = predict_model_space(model, np.tile(model.latents[2], (4, 1)), x)
    diagonal = np.stack([np.diag(c) for c in cov], axis=1)
    np.testing.assert_allclose(diagonal + model.hyperparameters.noise_variance, variance, rtol=1e-9)


def test_joint_likelihood_matches_a_dense_gaussian_built_from_the_kernel(
    model: ManifoldModel,
) -> None:
    """Brute force: condition the joint Gaussian of [training y; trial y] directly."""
    x, y = _trial(5, 4)
    h = model.hyperparameters
    data = model.data
    variance = np.array([0.004, 0.0, 0.008])
    expected = np.zeros(data.n_objects)
    for obj in range(data.n_objects):
        for a in range(3):
            z_train = np.hstack([model.latents[data.object_index], data.actions])
            z_trial = np.hstack([np.tile(model.latents[obj], (5, 1)), x])
            scales = np.concatenate([h.latent_lengthscales[a], h.action_lengthscales[a]])
            everything = np.vstack([z_train, z_trial])
            prior = h.signal_variance[a] * squared_exponential(everything, everything, scales)
            n = data.n_touches
            noise = np.zeros_like(prior)
            noise[:n, :n] = h.noise_variance[a] * np.eye(n)
            noise[n:, n:] = variance[a] * np.ones((5, 5)) + (
                h.noise_variance[a] - variance[a]
            ) * np.eye(5)
            joint = prior + noise
            gain = np.linalg.solve(joint[:n, :n], joint[:n, n:]).T
            centred = data.observations[:, a] - data.observation_mean[a]
            mean = data.observation_mean[a] + gain @ centred
            cov = joint[n:, n:] - gain @ joint[:n, n:]
            expected[obj] += scipy.stats.multivariate_normal(mean, cov).logpdf(y[:, a])
    np.testing.assert_allclose(trial_log_likelihoods(model, x, y, variance), expected, rtol=1e-7)


def test_shared_offset_evidence_saturates(model: ManifoldModel) -> None:
    """The same touch repeated: independent evidence grows linearly, with σ_b² it levels off."""
    x, y = _trial(1, 5)
    variance = 0.8 * model.hyperparameters.noise_variance
    gaps_independent, gaps_joint = [], []
    for t in (1, 4, 16):
        xs, ys = np.repeat(x, t, axis=0), np.repeat(y, t, axis=0)
        independent = object_log_likelihoods(model, xs, ys, "independent")
        joint = trial_log_likelihoods(model, xs, ys, variance)
        gaps_independent.append(np.ptp(independent))
        gaps_joint.append(np.ptp(joint))
    np.testing.assert_allclose(gaps_independent[2], 16 * gaps_independent[0], rtol=1e-9)
    assert gaps_joint[2] < 2.0 * gaps_joint[0]
    assert gaps_joint[2] - gaps_joint[1] < gaps_joint[1] - gaps_joint[0]


def test_repeated_touches_far_from_the_data_saturate_without_a_placement_effect(
    model: ManifoldModel,
) -> None:
    """V alone: k identical touches where the GP extrapolates are worth less than k touches."""
    rng = np.random.default_rng(12)
    x = np.array([[2.5]])  # the training actions are N(0, 1)
    y = Experiment1World().observe(1, x, rng)
    one = np.ptp(object_log_likelihoods(model, x, y))
    np.testing.assert_allclose(one, np.ptp(object_log_likelihoods(model, x, y, "independent")))
    gaps = []
    for k in (4, 16):
        xs, ys = np.repeat(x, k, axis=0), np.repeat(y, k, axis=0)
        gaps.append(np.ptp(object_log_likelihoods(model, xs, ys)))
        independent = np.ptp(object_log_likelihoods(model, xs, ys, "independent"))
        np.testing.assert_allclose(independent, k * one, rtol=1e-9)
        assert gaps[-1] < 0.75 * k * one
    assert gaps[1] - gaps[0] < 3 * (gaps[0] - one)


def test_negative_or_too_large_variance_is_refused(model: ManifoldModel) -> None:
    x, y = _trial(2, 6)
    for bad in (np.array([-1e-3, 0.0, 0.0]), model.hyperparameters.noise_variance):
        with pytest.raises(InvalidInputError, match="placement_variance"):
            trial_log_likelihoods(model, x, y, bad)


def placed_experiment1(
    offset_std: float | tuple[float, ...], seed: int, run: int = 5
) -> tuple[ManifoldModel, np.ndarray]:
    """Experiment 1, 100 touches per object in placements of ``run``, each sharing an offset of
    spread ``offset_std`` (one for every object, or one per object)."""
    rng = np.random.default_rng(seed)
    base = sample_experiment1(rng, touches_per_object=100, noise_std=0.1)
    spread = np.broadcast_to(np.asarray(offset_std, dtype=np.float64), (base.n_objects,))
    placement = np.zeros(base.n_touches, dtype=np.int64)
    observations = base.observations.copy()
    for obj in range(base.n_objects):
        rows = np.flatnonzero(base.object_index == obj)
        placement[rows] = np.arange(rows.size) // run
        for p in range(rows.size // run):
            observations[rows[placement[rows] == p]] += rng.normal(0.0, spread[obj], size=3)
    data = TrainingData(base.object_names, base.object_index, base.actions, observations, placement)
    theta = np.asarray(EXPERIMENT1_THETAS)[:, None]
    centred = theta - theta.mean()
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.full(3, 0.01 + float(np.mean(spread**2))),
        latent_lengthscales=np.array([[1.9], [100.0], [8.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )
    return condition(data, centred / np.sqrt(np.mean(centred**2)), hyper), placement


def test_estimator_recovers_the_placement_variance() -> None:
    model, placement = placed_experiment1(0.1, 7)
    estimate = estimate_placement_variance(model, placement)
    assert estimate.groups == 80
    assert estimate.pairs == 80 * 5 * 4
    # σ_b² = 0.01 per feature; 80 placements give a relative standard error of about 0.2.
    assert np.all(estimate.variance > 0.005)
    assert np.all(estimate.variance < 0.016)


def test_estimator_finds_no_effect_without_offsets() -> None:
    model, placement = placed_experiment1(0.0, 8)
    estimate = estimate_placement_variance(model, placement)
    assert np.all(np.abs(estimate.raw_variance) < 0.002)


def test_with_placement_effect_uses_the_recorded_placements(model: ManifoldModel) -> None:
    unchanged, none = with_placement_effect(model)
    assert unchanged is model
    assert none is None
    placed, placement = placed_experiment1(0.1, 9)
    fitted, estimate = with_placement_effect(placed)
    assert estimate is not None
    np.testing.assert_array_equal(fitted.placement_variance, estimate.variance)
    assert len(placement_groups(placed.data.object_index, placement)) == 80
    # Every touch its own placement (the default collection): nothing to estimate, no effect.
    data = placed.raw_data
    singles = dataclasses.replace(placed, data=dataclasses.replace(
        data, placement_index=np.arange(data.n_touches)))  # fmt: skip
    alone, nothing = with_placement_effect(singles)
    assert alone is singles
    assert nothing is None


@pytest.mark.parametrize(
    ("placement_share", "seed"),
    [(0.5, 10), (0.0, 13)],
    ids=["with a placement effect", "without"],
)
def test_session_posterior_is_the_batch_joint_at_every_step(
    model: ManifoldModel, placement_share: float, seed: int
) -> None:
    """With or without a placement effect, the session scores a trial's touches jointly."""
    placed = (
        dataclasses.replace(
            model, placement_variance=placement_share * model.hyperparameters.noise_variance
        )
        if placement_share
        else model
    )
    x, y = _trial(5, seed)
    session = RecognitionSession(
        placed, Planner(placed, PassivePolicy()), settings=RecognitionSettings(max_steps=5)
    )
    for t in range(5):
        step = session.observe(x[t], y[t])
        np.testing.assert_allclose(
            step.probabilities, object_posterior(placed, x[: t + 1], y[: t + 1]), rtol=1e-12
        )


def test_independent_setting_reproduces_the_product_posterior_bit_for_bit(
    model: ManifoldModel,
) -> None:
    """The session's old update: add each touch's independent log-likelihoods, normalise."""
    x, y = _trial(5, 14)
    placed = dataclasses.replace(
        model, placement_variance=0.5 * model.hyperparameters.noise_variance
    )
    settings = RecognitionSettings(max_steps=5, trial_likelihood="independent")
    session = RecognitionSession(placed, Planner(placed, PassivePolicy()), settings=settings)
    total = np.zeros(model.data.n_objects)
    for t in range(5):
        step = session.observe(x[t], y[t])
        total = total + object_log_likelihoods(model, x[t : t + 1], y[t : t + 1], "independent")
        assert np.array_equal(step.probabilities, normalise_log_probabilities(total))


def test_unknown_trial_likelihood_is_refused() -> None:
    with pytest.raises(InvalidInputError, match="trial_likelihood"):
        RecognitionSettings(trial_likelihood="product")  # type: ignore[arg-type]
