"""A placement's shift of the action (core.gp.input_shift): the slope, the covariance it adds, its
estimate from the touches that share a placement, the trial likelihood and the model's own
samples."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.stats

from core.errors import InvalidInputError
from core.evaluation.trial_engine import ModelTrial
from core.evaluation.worlds import EXPERIMENT1_THETAS, experiment1_h
from core.gp.input_shift import (
    check_shift_variance,
    estimate_shift_variance,
    mean_jacobian,
    shared_shift_variance,
    shift_covariance,
    with_input_shift,
)
from core.gp.placement_effect import predictive_covariance
from core.gp.posterior import condition, predict_model_space
from core.recognition.object_posterior import object_log_likelihoods
from core.types import Hyperparameters, ManifoldModel, TrainingData


def two_action_model(seed: int = 0) -> ManifoldModel:
    """Three objects, 2-D actions, two features: a small dense model with unequal length-scales."""
    rng = np.random.default_rng(seed)
    n = 60
    obj = np.repeat(np.arange(3), n // 3)
    actions = rng.normal(size=(n, 2))
    latents = np.array([[-1.0], [0.2], [1.1]])
    observations = np.column_stack(
        [
            np.sin(1.3 * actions[:, 0] + latents[obj, 0]) + 0.5 * actions[:, 1],
            np.tanh(2.0 * actions[:, 1] * latents[obj, 0]),
        ]
    ) + 0.05 * rng.normal(size=(n, 2))
    data = TrainingData(("a", "b", "c"), obj, actions, observations)
    hyper = Hyperparameters(
        signal_variance=np.array([0.8, 0.5]),
        noise_variance=np.array([0.01, 0.02]),
        latent_lengthscales=np.array([[1.2], [0.9]]),
        action_lengthscales=np.array([[0.9, 1.7], [1.4, 0.6]]),
    )
    return condition(data, latents, hyper)


def test_the_slope_matches_finite_differences_of_the_mean() -> None:
    model = two_action_model()
    rng = np.random.default_rng(1)
    latents = rng.normal(size=(7, 1))
    actions = rng.normal(size=(7, 2))
    jac = mean_jacobian(model, latents, actions)
    assert jac.shape == (7, 2, 2)
    step = 1e-5
    for k in range(2):
        shift = np.zeros(2)
        shift[k] = step
        up, _ = predict_model_space(model, latents, actions + shift)
        down, _ = predict_model_space(model, latents, actions - shift)
        np.testing.assert_allclose(jac[:, :, k], (up - down) / (2 * step), rtol=1e-6, atol=1e-8)


def test_the_covariance_is_the_slope_times_the_shift_shared_or_per_touch() -> None:
    model = two_action_model()
    latent = np.array([0.3])
    actions = np.array([[0.1, -0.4], [1.2, 0.3], [-0.7, 0.9]])
    variance = np.array([0.04, 0.09])
    jac = mean_jacobian(model, np.tile(latent, (3, 1)), actions)
    cov = shift_covariance(model, latent, actions, variance)
    for a in range(2):
        for b in range(2):
            for t in range(3):
                for u in range(3):
                    expected = jac[t, a] @ np.diag(variance) @ jac[u, b]
                    assert cov[a * 3 + t, b * 3 + u] == pytest.approx(expected, abs=1e-14)
    own = shift_covariance(model, latent, actions, variance, shared=False)
    touch = np.tile(np.arange(3), 2)
    same = touch[:, None] == touch[None, :]
    np.testing.assert_array_equal(own[same], cov[same])
    assert np.all(own[~same] == 0.0)


def test_the_trial_likelihood_is_the_direct_gaussian_with_the_shift() -> None:
    model = two_action_model()
    creep = np.array([0.03, 0.01])
    shifted = dataclasses.replace(
        model,
        shift_variance=np.array([0.05, 0.2]),
        shift_creep_variance=creep,
        placement_variance=np.array([0.004, 0.01]),
    )
    rng = np.random.default_rng(3)
    actions = rng.normal(size=(4, 2))
    observations = rng.normal(size=(4, 2))
    for shared in (True, False):
        got = object_log_likelihoods(shifted, actions, observations, shared_placement=shared)
        for obj in range(3):
            latent = model.latents[obj]
            mean, _ = predict_model_space(model, np.tile(latent, (4, 1)), actions)
            cov_f = predictive_covariance(model, latent, actions)
            sigma_b = shifted.placement_variance if shared else np.zeros(2)
            assert sigma_b is not None
            noise = model.hyperparameters.noise_variance - sigma_b
            cov = scipy.linalg.block_diag(
                *[cov_f[a] + sigma_b[a] + noise[a] * np.eye(4) for a in range(2)]
            )
            cov += shift_covariance(model, latent, actions, np.array([0.05, 0.2]), shared, creep)
            expected = scipy.stats.multivariate_normal(mean.T.reshape(-1), cov).logpdf(
                observations.T.reshape(-1)
            )
            assert got[obj] == pytest.approx(expected, rel=1e-10)
    # No shift at all: the likelihood without the field, to rounding.
    zero = dataclasses.replace(model, shift_variance=np.zeros(2))
    np.testing.assert_allclose(
        object_log_likelihoods(zero, actions, observations),
        object_log_likelihoods(model, actions, observations),
        rtol=1e-12,
    )


def test_pairs_recover_a_known_shared_shift() -> None:
    """Residuals of placements of three touches drawn with the model's covariance plus a shared
    J Σ Jᵀ: the cross-products give Σ back, and nothing when there is no shared shift."""
    rng = np.random.default_rng(5)
    dy, dx, true = 3, 2, np.array([0.3, 0.05])
    residuals, plain, covariances, jacobians = [], [], [], []
    for _ in range(1500):
        jac = rng.normal(size=(3, dy, dx))
        base = rng.uniform(0.2, 1.0, size=(dy, 1, 1)) * (np.eye(3) + 0.3)  # (dy, 3, 3)
        full = scipy.linalg.block_diag(*base)  # feature-major (a·3 + t)
        rows = np.transpose(jac, (1, 0, 2)).reshape(dy * 3, dx)
        draw = rng.multivariate_normal(np.zeros(dy * 3), full + (rows * true) @ rows.T)
        residuals.append(draw.reshape(dy, 3).T)
        plain.append(rng.multivariate_normal(np.zeros(dy * 3), full).reshape(dy, 3).T)
        covariances.append(base)
        jacobians.append(jac)
    estimate, creep, pairs = shared_shift_variance(residuals, covariances, jacobians, np.ones(dx))
    assert pairs == 1500 * 6
    np.testing.assert_allclose(estimate, true, rtol=0.15)
    assert np.all(creep < 0.02)  # a shared shift that does not creep
    estimate, creep, _ = shared_shift_variance(plain, covariances, jacobians, np.ones(dx))
    assert np.all(estimate < 0.02)
    assert np.all(creep < 0.02)
    # Capped at twice the design's spread.
    capped, _, _ = shared_shift_variance(residuals, covariances, jacobians, np.full(dx, 0.01))
    np.testing.assert_allclose(capped, [0.04, 0.04])


def test_runs_of_four_recover_a_known_creep_and_pairs_cannot_see_it() -> None:
    """Residuals of placements of four touches whose shift creeps as a random walk (σ_c² =
    0.4 σ_δ²): the cross-products give σ_δ² and σ_c² back; the first two touches of each alone
    give σ_δ² and no creep (min(t, u) = 0 for every pair)."""
    rng = np.random.default_rng(8)
    dy, dx, n = 3, 2, 4
    shift, creep = np.array([0.2, 0.05]), np.array([0.08, 0.02])
    touch = np.tile(np.arange(n), dy)
    steps = np.minimum(touch[:, None], touch[None, :])
    residuals, covariances, jacobians = [], [], []
    for _ in range(2000):
        jac = rng.normal(size=(n, dy, dx))
        base = rng.uniform(0.2, 1.0, size=(dy, 1, 1)) * (np.eye(n) + 0.3)
        rows = np.transpose(jac, (1, 0, 2)).reshape(dy * n, dx)
        shared = (rows * shift) @ rows.T + steps * ((rows * creep) @ rows.T)
        draw = rng.multivariate_normal(np.zeros(dy * n), scipy.linalg.block_diag(*base) + shared)
        residuals.append(draw.reshape(dy, n).T)
        covariances.append(base)
        jacobians.append(jac)
    variance, crept, pairs = shared_shift_variance(residuals, covariances, jacobians, np.ones(dx))
    assert pairs == 2000 * 12
    np.testing.assert_allclose(variance, shift, rtol=0.15)
    np.testing.assert_allclose(crept, creep, rtol=0.2)
    np.testing.assert_allclose(crept / variance, crept[0] / variance[0])  # σ_c² = κ σ_δ²
    first = [r[:2] for r in residuals]
    bases = [c[:, :2, :2] for c in covariances]
    slopes = [j[:2] for j in jacobians]
    variance, crept, _ = shared_shift_variance(first, bases, slopes, np.ones(dx))
    np.testing.assert_allclose(variance, shift, rtol=0.2)
    np.testing.assert_array_equal(crept, 0.0)


def test_the_creep_adds_the_slope_times_min_t_u_times_its_variance() -> None:
    model = two_action_model()
    latent = np.array([-0.4])
    actions = np.array([[0.1, -0.4], [1.2, 0.3], [-0.7, 0.9], [0.5, 0.5]])
    variance, creep = np.array([0.04, 0.09]), np.array([0.02, 0.01])
    jac = mean_jacobian(model, np.tile(latent, (4, 1)), actions)
    cov = shift_covariance(model, latent, actions, variance, creep=creep)
    for a in range(2):
        for b in range(2):
            for t in range(4):
                for u in range(4):
                    expected = jac[t, a] @ np.diag(variance + creep * min(t, u)) @ jac[u, b]
                    assert cov[a * 4 + t, b * 4 + u] == pytest.approx(expected, abs=1e-14)
    # Each touch placed anew: every touch is a placement's first, no creep.
    np.testing.assert_array_equal(
        shift_covariance(model, latent, actions, variance, shared=False, creep=creep),
        shift_covariance(model, latent, actions, variance, shared=False),
    )


def experiment1_with_shift(shift_std: float, shared: bool, seed: int) -> ManifoldModel:
    """Experiment 1 (paper eq. (6)), 100 touches per object placed in pairs, each press landing
    off by a shift of std ``shift_std``: one shift per placement (``shared``) or one per touch.
    Conditioned at the true latents and hyperparameters near the fitted ones."""
    rng = np.random.default_rng(seed)
    theta = np.asarray(EXPERIMENT1_THETAS)
    obj = np.repeat(np.arange(4), 100)
    placement = np.tile(np.arange(100) // 2, 4)
    actions = rng.normal(size=(400, 1))
    shift = rng.normal(size=(400, 1)) if not shared else rng.normal(size=(4, 50, 1))[obj, placement]
    landed = actions + shift_std * shift
    observations = np.vstack(
        [experiment1_h(float(theta[o]), landed[i : i + 1]) for i, o in enumerate(obj)]
    )
    observations += 0.1 * rng.normal(size=observations.shape)
    data = TrainingData(
        ("o1", "o2", "o3", "o4"), obj, actions, observations, placement_index=placement
    )
    centred = (theta - theta.mean())[:, None]
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.full(3, 0.01 + 0.02 * shift_std),
        latent_lengthscales=np.array([[1.9], [100.0], [8.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )
    return condition(data, centred / np.sqrt(np.mean(centred**2)), hyper)


def test_the_estimate_sees_a_shift_the_placement_shares_and_not_one_each_touch_draws() -> None:
    shared = estimate_shift_variance(experiment1_with_shift(0.25, True, 0))
    own = estimate_shift_variance(experiment1_with_shift(0.25, False, 0))
    assert shared is not None
    assert own is not None
    assert shared.groups == 200
    assert shared.pairs == 400
    assert 0.25**2 / 3 < shared.variance[0] < 3 * 0.25**2
    assert own.variance[0] < shared.variance[0] / 5
    # No placements recorded: no estimate.
    model = experiment1_with_shift(0.25, True, 0)
    unplaced = dataclasses.replace(
        model, data=dataclasses.replace(model.data, placement_index=None)
    )
    assert estimate_shift_variance(unplaced) is None


def model_world_draws(
    model: ManifoldModel,
    target: str,
    actions: np.ndarray,
    trials: int,
    rng: np.random.Generator,
    shared_placement: bool = True,
) -> np.ndarray:
    """The observations of ``trials`` model-world trials touching ``target`` at ``actions``.
    Shape (trials, T, dy)."""
    draws = np.empty((trials, actions.shape[0], model.hyperparameters.observation_dim))
    for i in range(trials):
        trial = ModelTrial(model, target, shared_placement=shared_placement)
        draws[i] = [trial.touch(a, rng).observation for a in actions]
    return draws


def test_the_model_world_draws_the_shift_once_per_placement() -> None:
    """Across many model-world trials the two touches' model-space draws covary by J₁ Σ J₂ᵀ (the
    model has no placement or drift variance, so nothing else is shared)."""
    shift = np.array([1.0, 0.6])
    model = dataclasses.replace(two_action_model(), shift_variance=shift)
    actions = np.array([[0.4, -0.2], [-0.5, 0.8]])
    rng = np.random.default_rng(6)
    draws = model_world_draws(model, "b", actions, 2000, rng)
    jac = mean_jacobian(model, np.tile(model.latents[1], (2, 1)), actions)
    expected = jac[0] @ np.diag(shift) @ jac[1].T  # (dy, dy)
    centred = draws - draws.mean(axis=0)
    got = np.einsum("na,nb->ab", centred[:, 0], centred[:, 1]) / draws.shape[0]
    _, variance = predict_model_space(model, np.tile(model.latents[1], (2, 1)), actions)
    scale = np.sqrt(np.outer(variance[0], variance[1]) + np.abs(expected))
    np.testing.assert_allclose(got, expected, atol=5 * scale.max() / np.sqrt(draws.shape[0]))
    assert np.abs(expected).max() > 10 * scale.max() / np.sqrt(draws.shape[0])
    # Placed anew before every touch: nothing shared.
    fresh = model_world_draws(model, "b", actions, 2000, rng, shared_placement=False)
    centred = fresh - fresh.mean(axis=0)
    got = np.einsum("na,nb->ab", centred[:, 0], centred[:, 1]) / fresh.shape[0]
    np.testing.assert_allclose(got, 0.0, atol=5 * scale.max() / np.sqrt(fresh.shape[0]))
    # One touch's variance gains J Σ Jᵀ's diagonal.
    own = np.einsum("ak,k,ak->a", jac[0], shift, jac[0])
    np.testing.assert_allclose(
        draws[:, 0].var(axis=0), variance[0] + own, rtol=5 * np.sqrt(2 / draws.shape[0])
    )


def test_a_shift_variance_must_be_dx_values_at_least_zero() -> None:
    model = two_action_model()
    np.testing.assert_array_equal(check_shift_variance(model, [0.0, 0.5]), [0.0, 0.5])
    with pytest.raises(InvalidInputError, match="shift_variance"):
        check_shift_variance(model, [0.1, -0.5])
    with pytest.raises(InvalidInputError, match="shift_variance"):
        check_shift_variance(model, [0.1])


def test_the_model_world_creeps_the_shift_from_touch_to_touch() -> None:
    """Touches 2 and 3 of a trial covary by J₂ (Σ + σ_c²) J₃ᵀ, touches 1 and 3 by J₁ Σ J₃ᵀ."""
    shift, creep = np.array([0.5, 0.3]), np.array([0.6, 0.4])
    model = dataclasses.replace(
        two_action_model(), shift_variance=shift, shift_creep_variance=creep
    )
    actions = np.array([[0.4, -0.2], [-0.5, 0.8], [0.1, 0.3]])
    rng = np.random.default_rng(9)
    draws = model_world_draws(model, "c", actions, 3000, rng)
    jac = mean_jacobian(model, np.tile(model.latents[2], (3, 1)), actions)
    centred = draws - draws.mean(axis=0)
    _, variance = predict_model_space(model, np.tile(model.latents[2], (3, 1)), actions)
    for t, u in ((0, 2), (1, 2)):
        expected = jac[t] @ np.diag(shift + creep * min(t, u)) @ jac[u].T
        got = np.einsum("na,nb->ab", centred[:, t], centred[:, u]) / draws.shape[0]
        scale = np.sqrt(np.outer(variance[t], variance[u]) + np.abs(expected))
        np.testing.assert_allclose(got, expected, atol=5 * scale.max() / np.sqrt(draws.shape[0]))
    crept = jac[1] @ np.diag(creep) @ jac[2].T
    assert np.abs(crept).max() > 10 * scale.max() / np.sqrt(draws.shape[0])


def experiment1_with_creep(seed: int, reverse_rows: bool) -> ManifoldModel:
    """Experiment 1 with placements of four touches whose shift (std 0.2) creeps by std 0.2 per
    touch; the touches' times give their order (the rows reversed when ``reverse_rows``)."""
    rng = np.random.default_rng(seed)
    theta = np.asarray(EXPERIMENT1_THETAS)
    n = 160
    obj = np.repeat(np.arange(4), n)
    placement = np.tile(np.arange(n) // 4, 4)
    position = np.tile(np.arange(n) % 4, 4)
    start = 0.2 * rng.normal(size=(4, n // 4, 1))  # δ_0 of each placement
    crept = np.cumsum(0.2 * rng.normal(size=(4, n // 4, 3)), axis=2)  # Σ_{i<t} ε_i, t = 1..3
    walk = np.concatenate([start, start + crept], axis=2)  # (object, placement, position)
    shift = walk[obj, placement, position][:, None]
    actions = rng.normal(size=(4 * n, 1))
    observations = np.vstack(
        [experiment1_h(float(theta[o]), actions[i : i + 1] + shift[i]) for i, o in enumerate(obj)]
    )
    observations += 0.1 * rng.normal(size=observations.shape)
    times = np.arange(4 * n, dtype=np.float64)
    rows = np.arange(4 * n)[::-1] if reverse_rows else np.arange(4 * n)
    data = TrainingData(
        ("o1", "o2", "o3", "o4"),
        obj[rows],
        actions[rows],
        observations[rows],
        placement_index=placement[rows],
        touch_times_s=times[rows],
    )
    centred = (theta - theta.mean())[:, None]
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.full(3, 0.02),
        latent_lengthscales=np.array([[1.9], [100.0], [8.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )
    return condition(data, centred / np.sqrt(np.mean(centred**2)), hyper)


def test_runs_of_four_touches_show_the_creep_in_the_order_of_their_times() -> None:
    estimate = estimate_shift_variance(experiment1_with_creep(0, reverse_rows=False))
    assert estimate is not None
    assert (estimate.groups, estimate.runs, estimate.pairs) == (160, 160, 160 * 12)
    assert 0.04 / 3 < estimate.variance[0] < 3 * 0.04
    assert 0.04 / 3 < estimate.creep[0] < 3 * 0.04
    # The same touches written last to first: their times put them back in order.
    reversed_rows = estimate_shift_variance(experiment1_with_creep(0, reverse_rows=True))
    assert reversed_rows is not None
    np.testing.assert_allclose(reversed_rows.creep, estimate.creep, rtol=1e-8)
    np.testing.assert_allclose(reversed_rows.variance, estimate.variance, rtol=1e-8)
    # Scoring with the estimate: with_input_shift carries the creep into the model.
    model, _ = with_input_shift(experiment1_with_creep(0, reverse_rows=False))
    assert model.shift_creep_variance is not None
    np.testing.assert_array_equal(model.shift_creep_variance, estimate.creep)


def test_pairs_alone_leave_the_model_without_creep() -> None:
    model, estimate = with_input_shift(experiment1_with_shift(0.25, True, 0))
    assert estimate is not None
    assert estimate.runs == 0
    assert model.shift_creep_variance is None


def experiment1_with_a_second_action(seed: int) -> ManifoldModel:
    """Experiment 1 with a second action dimension that the response follows smoothly and that no
    placement shifts: pairs share a shift of std 0.25 along the first dimension only."""
    rng = np.random.default_rng(seed)
    theta = np.asarray(EXPERIMENT1_THETAS)
    obj = np.repeat(np.arange(4), 100)
    placement = np.tile(np.arange(100) // 2, 4)
    actions = rng.normal(size=(400, 2))
    landed = actions[:, :1] + 0.25 * rng.normal(size=(4, 50, 1))[obj, placement]
    observations = np.vstack(
        [experiment1_h(float(theta[o]), landed[i : i + 1]) for i, o in enumerate(obj)]
    )
    observations += 0.3 * np.sin(actions[:, 1:2]) + 0.1 * rng.normal(size=observations.shape)
    data = TrainingData(
        ("o1", "o2", "o3", "o4"), obj, actions, observations, placement_index=placement
    )
    centred = (theta - theta.mean())[:, None]
    hyper = Hyperparameters(
        signal_variance=np.array([0.25, 0.25, 0.3]),
        noise_variance=np.full(3, 0.015),
        latent_lengthscales=np.array([[1.9], [100.0], [8.0]]),
        action_lengthscales=np.array([[0.84, 1.5], [0.88, 1.5], [0.92, 1.5]]),
    )
    return condition(data, centred / np.sqrt(np.mean(centred**2)), hyper)


def test_the_shift_estimated_along_chosen_dimensions_only() -> None:
    model = experiment1_with_a_second_action(1)
    free = estimate_shift_variance(model)
    every = estimate_shift_variance(model, np.array([1, 0]))
    first = estimate_shift_variance(model, np.array([0]))
    assert free is not None
    assert every is not None
    assert first is not None
    # Every dimension named is the default, to the bit.
    np.testing.assert_array_equal(every.variance, free.variance)
    # Along the first alone: the placements' shift recovered, nothing on the other dimension.
    assert first.variance[1] == 0.0
    assert 0.25**2 / 3 < first.variance[0] < 3 * 0.25**2
    assert first.pairs == free.pairs
    shifted, estimate = with_input_shift(model, np.array([0]))
    assert estimate is not None
    assert shifted.shift_variance is not None
    np.testing.assert_array_equal(shifted.shift_variance, first.variance)


@pytest.mark.parametrize("dimensions", [[], [0, 0], [2], [-1], [0.5]])
def test_shift_dimensions_must_be_distinct_action_dimensions(dimensions: list[float]) -> None:
    model = experiment1_with_a_second_action(1)
    with pytest.raises(InvalidInputError, match=r"shift_dimensions: expected distinct .* 0\.\.1"):
        estimate_shift_variance(model, np.array(dimensions))
