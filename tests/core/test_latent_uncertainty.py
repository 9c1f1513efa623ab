"""Each object's latent point as uncertain: its Laplace covariance and the object likelihood that
integrates over it (docs/method.md (L1)–(L3))."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.gp.kernels import squared_exponential
from core.gp.likelihood import negative_log_likelihood, negative_log_likelihood_and_gradient
from core.gp.placement_effect import trial_log_likelihoods as point_trial_log_likelihoods
from core.gp.posterior import condition
from core.recognition import RecognitionSession, RecognitionSettings
from core.recognition.latent_uncertainty import (
    check_latent_covariance,
    laplace_latents,
    latent_hessians,
    trial_log_likelihoods,
    trial_moments,
    with_latent_uncertainty,
)
from core.recognition.object_posterior import object_log_likelihoods
from core.recognition.planning import PassivePolicy, Planner
from core.types import Hyperparameters, ManifoldModel, TrainingData

_LATENTS = np.array([[1.0, 0.0], [-0.5, 0.8], [-0.5, -0.8]])


def _world(latent: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Two features, smooth in (s, x)."""
    return np.stack(
        [np.sin(x[:, 0] + latent[0]) + 0.5 * latent[1], np.cos(0.7 * x[:, 0] - latent[1])],
        axis=1,
    )


@pytest.fixture(scope="module")
def model() -> ManifoldModel:
    rng = np.random.default_rng(3)
    per_object = 12
    index = np.repeat(np.arange(3), per_object)
    x = rng.normal(size=(index.size, 1))
    y = np.concatenate([_world(_LATENTS[obj], x[index == obj]) for obj in range(3)])
    y += 0.05 * rng.normal(size=y.shape)
    data = TrainingData(("a", "b", "c"), index, x, y)
    hyper = Hyperparameters(
        signal_variance=np.array([0.6, 0.4]),
        noise_variance=np.array([0.003, 0.004]),
        latent_lengthscales=np.array([[0.9, 1.3], [1.5, 0.7]]),
        action_lengthscales=np.array([[1.1], [1.4]]),
    )
    return condition(data, _LATENTS, hyper)


def test_hessian_matches_second_differences_of_the_likelihood(model: ManifoldModel) -> None:
    hessian = latent_hessians(model)
    h = model.hyperparameters
    step = 1e-3
    for obj in range(3):
        numeric = np.empty((2, 2))
        for i in range(2):
            for j in range(2):
                total = 0.0
                for si, sj, sign in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
                    moved = model.latents.copy()
                    moved[obj, i] += si * step
                    moved[obj, j] += sj * step
                    total += sign * negative_log_likelihood(model.data, moved, h)
                numeric[i, j] = total / (4 * step**2)
        np.testing.assert_allclose(hessian[obj], numeric, atol=1e-4 * np.abs(numeric).max())
        np.testing.assert_array_equal(hessian[obj], hessian[obj].T)


def latent_hessians_by_differences(model: ManifoldModel) -> np.ndarray:
    """H_l by central differences of the analytic gradient of (M2): 2 L ds evaluations, step
    1e-3 × the smallest latent length-scale, symmetrised (how the Laplace step once computed
    it). Shape (L, ds, ds)."""
    h = model.hyperparameters
    latents = np.array(model.latents, dtype=np.float64)
    n_objects, ds = latents.shape
    step = 1e-3 * float(np.min(h.latent_lengthscales))
    out = np.empty((n_objects, ds, ds))
    for obj in range(n_objects):
        for d in range(ds):
            gradients = []
            for sign in (1.0, -1.0):
                moved = latents.copy()
                moved[obj, d] += sign * step
                _, gradient = negative_log_likelihood_and_gradient(model.data, moved, h)
                gradients.append(gradient.latents[obj])
            out[obj, :, d] = (gradients[0] - gradients[1]) / (2.0 * step)
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def test_analytic_hessian_equals_differences_of_the_gradient(model: ManifoldModel) -> None:
    """Against central differences of the analytic gradient, on the fixture and on a world with
    unequal touch counts, dx = 2, ds = 3 and three features."""
    rng = np.random.default_rng(5)
    index = np.repeat(np.arange(4), [5, 9, 7, 12])
    x = rng.normal(size=(index.size, 2))
    latents = rng.normal(size=(4, 3))
    y = np.stack(
        [np.sin(x[:, 0] + latents[index, 0]), x[:, 1] * latents[index, 1], latents[index, 2]],
        axis=1,
    ) + 0.1 * rng.normal(size=(index.size, 3))
    hyper = Hyperparameters(
        signal_variance=np.array([0.8, 0.5, 1.2]),
        noise_variance=np.array([0.01, 0.02, 0.015]),
        latent_lengthscales=rng.uniform(0.6, 2.0, size=(3, 3)),
        action_lengthscales=rng.uniform(0.8, 1.5, size=(3, 2)),
    )
    other = condition(TrainingData(("a", "b", "c", "d"), index, x, y), latents, hyper)
    for case in (model, other):
        analytic, numeric = latent_hessians(case), latent_hessians_by_differences(case)
        assert analytic.shape == numeric.shape
        np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max())


def test_laplace_covariance_is_the_inverse_hessian_with_a_floor(model: ManifoldModel) -> None:
    laplace = laplace_latents(model)
    for obj in range(3):
        values = np.linalg.eigvalsh(laplace.hessian[obj])
        if values.min() > 1.0:
            np.testing.assert_allclose(
                laplace.covariance[obj], np.linalg.inv(laplace.hessian[obj]), rtol=1e-10
            )
            assert laplace.floored[obj] == 0
    tight = laplace_latents(model, max_variance=1e-9)
    np.testing.assert_allclose(
        tight.covariance, np.broadcast_to(1e-9 * np.eye(2), (3, 2, 2)), atol=1e-20
    )
    assert tight.floored == (2, 2, 2)
    with pytest.raises(InvalidInputError, match="max_variance"):
        laplace_latents(model, max_variance=0.0)


def test_more_touches_make_a_latent_more_certain(model: ManifoldModel) -> None:
    data = model.data
    doubled = TrainingData(
        data.object_names,
        np.concatenate([data.object_index, data.object_index]),
        np.concatenate([data.actions, data.actions + 0.01]),
        np.concatenate([data.observations, data.observations]),
    )
    more = condition(doubled, model.latents, model.hyperparameters)
    few = laplace_latents(model).covariance
    many = laplace_latents(more).covariance
    for obj in range(3):
        assert np.trace(many[obj]) < np.trace(few[obj])


def _monte_carlo_moments(
    model: ManifoldModel, latent: np.ndarray, cov: np.ndarray, x: np.ndarray, n: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """E[f] and Cov[f] over (feature, action) from samples of s, each with the GP's exact
    predictive at that s (law of total covariance), written directly from the kernel."""
    rng = np.random.default_rng(seed)
    samples = rng.multivariate_normal(latent, cov, size=n)  # (n, ds)
    h = model.hyperparameters
    data = model.data
    dy, t = h.observation_dim, x.shape[0]
    means = np.empty((n, dy, t))
    expected_cov = np.zeros((dy, t, t))
    for a in range(dy):
        k_s = squared_exponential(samples, model.latents, h.latent_lengthscales[a])  # (n, L)
        k_x = squared_exponential(x, data.actions, h.action_lengthscales[a])  # (t, N)
        k = h.signal_variance[a] * k_s[:, data.object_index][:, None, :] * k_x[None]  # (n,t,N)
        means[:, a] = k @ model.posterior.beta[a] + data.observation_mean[a]
        weighted = k @ model.posterior.gram_inverse[a]  # (n, t, N)
        inside = np.tensordot(weighted, k, axes=([0, 2], [0, 2])) / n
        prior = h.signal_variance[a] * squared_exponential(x, x, h.action_lengthscales[a])
        expected_cov[a] = prior - inside
    flat = means.reshape(n, dy * t)
    total = np.cov(flat, rowvar=False)
    for a in range(dy):
        total[a * t : (a + 1) * t, a * t : (a + 1) * t] += expected_cov[a]
    return flat.mean(axis=0).reshape(dy, t).T, total


def test_trial_moments_match_monte_carlo_over_the_latent(model: ManifoldModel) -> None:
    x = np.array([[-1.0], [0.2], [0.3], [1.5]])
    latent = model.latents[1]
    cov = np.array([[0.08, 0.02], [0.02, 0.05]])
    mean, moments_cov = trial_moments(model, latent, cov, x)
    mc_mean, mc_cov = _monte_carlo_moments(model, latent, cov, x, 40_000, 0)
    scale = np.sqrt(np.diag(moments_cov)).max()
    np.testing.assert_allclose(mean, mc_mean, atol=0.01 * scale)
    np.testing.assert_allclose(moments_cov, mc_cov, atol=0.02 * scale**2)
    # The features are correlated through the shared uncertain latent.
    assert np.abs(moments_cov[:4, 4:]).max() > 0.05 * scale**2


def test_vanishing_latent_variance_gives_todays_likelihood(model: ManifoldModel) -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=(5, 1))
    y = _world(_LATENTS[2], x) + 0.05 * rng.normal(size=(5, 2))
    tiny = np.broadcast_to(1e-12 * np.eye(2), (3, 2, 2)).copy()
    for variance in (np.zeros(2), 0.5 * model.hyperparameters.noise_variance):
        np.testing.assert_allclose(
            trial_log_likelihoods(model, x, y, variance, tiny),
            point_trial_log_likelihoods(model, x, y, variance),
            rtol=1e-8,
        )
    with_tiny = dataclasses.replace(model, latent_covariance=tiny)
    for setting in ("joint", "independent"):
        np.testing.assert_allclose(
            object_log_likelihoods(with_tiny, x, y, setting),
            object_log_likelihoods(model, x, y, setting),
            rtol=1e-8,
        )


def test_uncertain_latents_temper_a_confident_trial(model: ManifoldModel) -> None:
    """Touches of object c: under the point latents the log odds against the runner-up are
    larger than once s_l is integrated over its Laplace posterior; one touch under the joint
    setting equals the independent one."""
    uncertain, laplace = with_latent_uncertainty(model)
    assert np.all(np.linalg.eigvalsh(laplace.covariance) > 0)
    rng = np.random.default_rng(11)
    x = rng.normal(size=(6, 1))
    y = _world(_LATENTS[2], x) + 0.05 * rng.normal(size=(6, 2))
    point = object_log_likelihoods(model, x, y)
    widened = object_log_likelihoods(uncertain, x, y)
    assert np.argmax(point) == np.argmax(widened) == 2
    assert np.sort(point)[-1] - np.sort(point)[-2] > np.sort(widened)[-1] - np.sort(widened)[-2]
    np.testing.assert_allclose(
        object_log_likelihoods(uncertain, x[:1], y[:1], "joint"),
        object_log_likelihoods(uncertain, x[:1], y[:1], "independent"),
        rtol=1e-10,
    )


def test_session_uses_the_uncertain_latents_at_every_step(model: ManifoldModel) -> None:
    uncertain, _ = with_latent_uncertainty(model)
    session = RecognitionSession(
        uncertain,
        Planner(uncertain, PassivePolicy()),
        settings=RecognitionSettings(max_steps=4, tolerance=0.0),
    )
    rng = np.random.default_rng(2)
    x = rng.normal(size=(4, 1))
    y = _world(_LATENTS[0], x)
    for t in range(4):
        step = session.observe(x[t], y[t])
        expected = object_log_likelihoods(uncertain, x[: t + 1], y[: t + 1])
        probabilities = np.exp(expected - expected.max())
        np.testing.assert_allclose(step.probabilities, probabilities / probabilities.sum())


def test_bad_latent_covariance_is_refused(model: ManifoldModel) -> None:
    with pytest.raises(InvalidInputError, match="latent_covariance"):
        check_latent_covariance(model, np.zeros((2, 2, 2)))
    negative = np.broadcast_to(np.eye(2), (3, 2, 2)).copy()
    negative[1] = -np.eye(2)
    with pytest.raises(InvalidInputError, match="object 1"):
        check_latent_covariance(model, negative)
    skew = np.broadcast_to(np.eye(2), (3, 2, 2)).copy()
    skew[0, 0, 1] = 0.5
    with pytest.raises(InvalidInputError, match="symmetric"):
        check_latent_covariance(model, skew)
