"""The observation transform and the correlated noise model (core/gp/noise_model.py)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from core.errors import InvalidInputError
from core.evaluation.worlds import correlated_noise_world, sample_dataset
from core.gp.manifold import FitOptions, NoiseModelChoice, fit_manifold, iter_fit
from core.gp.noise_model import (
    attach_transform,
    correlated_transform,
    loo_log_likelihoods,
    standardising_transform,
    transform_data,
    warm_start,
    whitening_transform,
)
from core.gp.posterior import condition, gram_matrix, predict, predict_model_space
from core.observation_transform import ObservationTransform
from core.recognition.moments import (
    action_statistics,
    mutual_information,
    predictive_moments,
    update_belief,
)
from core.recognition.object_posterior import (
    object_log_likelihoods,
    object_posterior,
    touch_log_likelihoods,
)
from core.recognition.planning import FixedPolicy, Planner
from core.recognition.session import RecognitionSession
from core.types import GaussianBelief, Hyperparameters, ManifoldModel, TrainingData

HYPER = Hyperparameters(
    signal_variance=np.array([1.0, 0.8, 1.2]),
    noise_variance=np.array([0.05, 0.08, 0.06]),
    latent_lengthscales=np.array([[1.5, 2.0], [1.0, 1.2], [2.0, 1.5]]),
    action_lengthscales=np.array([[1.0], [1.3], [0.8]]),
)
LATENTS = np.array([[0.0, 1.0], [1.0, -0.5], [-1.0, -0.5], [0.3, 0.2]])


def raw_data(seed: int = 0, n: int = 12) -> TrainingData:
    rng = np.random.default_rng(seed)
    index = np.repeat(np.arange(4), n)
    x = rng.normal(size=(4 * n, 1))
    y = np.column_stack([np.sin(x[:, 0] + index), np.cos(x[:, 0] * index), x[:, 0] * 0.3 + index])
    noise = rng.multivariate_normal(
        np.zeros(3), [[1, 0.8, 0.3], [0.8, 1, 0.2], [0.3, 0.2, 1]], 4 * n
    )
    y = y + 0.2 * noise
    y = y * np.array([100.0, 1.0, 0.01]) + np.array([50.0, -2.0, 0.3])
    return TrainingData(("a", "b", "c", "d"), index, x, y)


def a_transform(data: TrainingData) -> ObservationTransform:
    """A correlated transform with a full, non-symmetric-looking whitening."""
    base = standardising_transform(data)
    covariance = np.array([[0.04, 0.02, 0.0], [0.02, 0.05, 0.01], [0.0, 0.01, 0.03]])
    return whitening_transform(base, covariance, "test")


def transformed_model(data: TrainingData, transform: ObservationTransform) -> ManifoldModel:
    model = condition(transform_data(data, transform), LATENTS, HYPER)
    return attach_transform(model, transform, data)


def test_identity_transform_reproduces_the_untransformed_model_exactly() -> None:
    data = raw_data()
    plain = condition(data, LATENTS, HYPER)
    identity = ObservationTransform.identity(3)
    model = transformed_model(data, identity)
    assert model.log_likelihood == plain.log_likelihood
    np.testing.assert_array_equal(model.posterior.beta, plain.posterior.beta)
    rng = np.random.default_rng(1)
    s, x = rng.normal(size=(7, 2)), rng.normal(size=(7, 1))
    for got, want in zip(predict(model, s, x), predict(plain, s, x), strict=True):
        np.testing.assert_array_equal(got, want)
    y = data.observations[:5]
    np.testing.assert_array_equal(
        object_log_likelihoods(model, data.actions[:5], y),
        object_log_likelihoods(plain, data.actions[:5], y),
    )


def test_transform_round_trips_and_jacobian() -> None:
    data = raw_data()
    transform = a_transform(data)
    y = data.observations
    np.testing.assert_allclose(transform.restore_mean(transform.apply(y)), y, rtol=1e-12)
    assert transform.log_jacobian == pytest.approx(np.log(abs(np.linalg.det(transform.matrix))))
    # y' = Σ_z^{-1/2} z whitens Σ_z: M Σ_ε Mᵀ = I with Σ_ε = D Σ_z D.
    sigma_raw = transform.restore_covariance(np.eye(3))
    np.testing.assert_allclose(
        transform.matrix @ sigma_raw @ transform.matrix.T, np.eye(3), atol=1e-10
    )
    assert transform.log_jacobian == pytest.approx(-0.5 * np.linalg.slogdet(sigma_raw)[1])


def test_predict_is_the_model_space_prediction_mapped_back() -> None:
    data = raw_data()
    transform = a_transform(data)
    model = transformed_model(data, transform)
    rng = np.random.default_rng(2)
    s, x = rng.normal(size=(6, 2)), rng.normal(size=(6, 1))
    mean, variance = predict(model, s, x)
    mean_m, variance_m = predict_model_space(model, s, x)
    np.testing.assert_allclose(mean, mean_m @ transform.inverse.T + transform.offset, rtol=1e-12)
    for q in range(6):
        full = transform.inverse @ np.diag(variance_m[q]) @ transform.inverse.T
        np.testing.assert_allclose(variance[q], np.diag(full), rtol=1e-12)
    # Predictions are in raw units: near the raw training observations' scale.
    assert np.abs(mean[:, 0]).max() > 10


def brute_force_log_likelihoods(model: ManifoldModel, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Σ_t log N(y_t; raw mean, full raw covariance) per object, one touch at a time."""
    transform = model.observation_transform
    out = np.zeros(model.latents.shape[0])
    for obj in range(model.latents.shape[0]):
        for t in range(x.shape[0]):
            mean_m, var_m = predict_model_space(model, model.latents[obj : obj + 1], x[t : t + 1])
            mean = transform.restore_mean(mean_m)[0]
            cov = transform.restore_covariance(np.diag(var_m[0]))
            out[obj] += scipy.stats.multivariate_normal(mean, cov).logpdf(y[t])
    return out


def test_object_posterior_matches_brute_force_in_raw_units() -> None:
    data = raw_data()
    model = transformed_model(data, a_transform(data))
    rng = np.random.default_rng(3)
    pick = rng.choice(data.n_touches, 3, replace=False)
    x, y = data.actions[pick], data.observations[pick]
    brute = brute_force_log_likelihoods(model, x, y)
    np.testing.assert_allclose(object_log_likelihoods(model, x, y, "independent"), brute, rtol=1e-9)
    expected = np.exp(brute - brute.max())
    np.testing.assert_allclose(
        object_posterior(model, x, y, "independent"), expected / expected.sum(), rtol=1e-9
    )
    per_touch = touch_log_likelihoods(model, data.object_index[pick], x, y)
    assert per_touch.sum() == pytest.approx(
        sum(
            brute_force_log_likelihoods(model, x[t : t + 1], y[t : t + 1])[data.object_index[p]]
            for t, p in enumerate(pick)
        ),
        rel=1e-9,
    )


def test_mutual_information_and_update_equal_the_direct_raw_space_computation() -> None:
    data = raw_data()
    transform = a_transform(data)
    model = transformed_model(data, transform)
    belief = GaussianBelief(np.array([0.2, 0.1]), np.array([[0.5, 0.1], [0.1, 0.4]]))
    x = np.array([[0.3]])
    moments = predictive_moments(model, belief, action_statistics(model, x))
    # Direct: the joint Gaussian of (s, y) in raw units, y = M⁻¹ y' + c.
    inverse = transform.inverse
    mean_raw = moments.mean[0] @ inverse.T + transform.offset
    cov_raw = inverse @ moments.cov[0] @ inverse.T
    cross_raw = moments.cross_cov[0] @ inverse.T  # cov(s, y) = cov(s, y') M⁻ᵀ, (ds, dy)
    sigma = belief.cov
    gain = cross_raw @ np.linalg.inv(cov_raw)
    mi_direct = 0.5 * (
        np.linalg.slogdet(sigma)[1] - np.linalg.slogdet(sigma - gain @ cross_raw.T)[1]
    )
    assert float(mutual_information(moments, belief)[0]) == pytest.approx(mi_direct, rel=1e-9)
    y_raw = data.observations[4]
    updated = update_belief(belief, moments, 0, transform.apply(y_raw[None, :])[0])
    np.testing.assert_allclose(updated.mean, belief.mean + gain @ (y_raw - mean_raw), rtol=1e-9)
    np.testing.assert_allclose(updated.cov, sigma - gain @ cross_raw.T, rtol=1e-9, atol=1e-12)
    # The recognition session maps the raw observation at its entry.
    session = RecognitionSession(model, Planner(model, FixedPolicy(x[0])), belief)
    step = session.observe(x[0], y_raw)
    np.testing.assert_allclose(step.belief.mean, updated.mean, rtol=1e-9)
    np.testing.assert_array_equal(step.observation, y_raw)


def test_log_likelihood_includes_the_jacobian() -> None:
    data = raw_data()
    transform = a_transform(data)
    model = transformed_model(data, transform)
    plain = condition(transform_data(data, transform), LATENTS, HYPER)
    expected = plain.log_likelihood + data.n_touches * transform.log_jacobian
    assert model.log_likelihood == pytest.approx(expected, rel=1e-12)
    loo = loo_log_likelihoods(model)
    assert loo is not None
    assert loo.shape == (data.n_touches,)


def test_loo_matches_refitting_without_the_touch() -> None:
    data = raw_data(n=5)
    transform = a_transform(data)
    model = transformed_model(data, transform)
    loo = loo_log_likelihoods(model)
    assert loo is not None
    i = 7
    z = transform_data(data, transform)
    centred = z.observations - z.observation_mean  # the model's constant mean, all touches
    rest = np.arange(data.n_touches) != i
    direct = 0.0
    for a in range(3):
        gram = gram_matrix(z, LATENTS, HYPER, a)
        k = gram[rest, i]
        solve = np.linalg.solve(gram[np.ix_(rest, rest)], np.column_stack([centred[rest, a], k]))
        mean, var = k @ solve[:, 0], gram[i, i] - k @ solve[:, 1]
        direct += scipy.stats.norm(mean, np.sqrt(var)).logpdf(centred[i, a])
    assert loo[i] == pytest.approx(direct + transform.log_jacobian, rel=1e-8)


def test_constant_feature_is_named() -> None:
    data = raw_data()
    y = data.observations.copy()
    y[:, 1] = 4.5
    constant = TrainingData(data.object_names, data.object_index, data.actions, y)
    with pytest.raises(InvalidInputError, match=r"y_2 \(= 4\.5 on every touch\)"):
        standardising_transform(constant)
    with pytest.raises(InvalidInputError, match="y_2"):
        fit_manifold(constant, 1, np.random.default_rng(0), noise_model="independent")


def test_wildly_different_scales_give_the_same_fit() -> None:
    world = correlated_noise_world(np.random.default_rng(4), n_objects=4, feature_scales=(1.0,) * 5)
    data = sample_dataset(world, np.random.default_rng(5), 12)
    scales = np.array([100.0, 30.0, 1.0, 0.01, 1.0])
    scaled = TrainingData(
        data.object_names, data.object_index, data.actions, data.observations * scales + 7.0
    )
    # Run to L-BFGS-B's own convergence: the stall rules stop wherever the path slows, and two
    # paths that differ by round-off slow at points ~0.01 nats apart.
    options = FitOptions(restarts=0, stall_nats=0.0, stall_relative=0.0, joint_stall_nats=0.0)
    a = fit_manifold(data, 1, np.random.default_rng(0), options, noise_model="independent")
    b = fit_manifold(scaled, 1, np.random.default_rng(0), options, noise_model="independent")
    # Standardised, both see the same numbers up to round-off and reach the same optimum; its
    # valley is flat along the latents (points 0.01 apart within 10⁻⁵ nats), so they agree to
    # a few hundredths, against a spread of 2.3.
    np.testing.assert_allclose(a.latents, b.latents, atol=0.03)
    # Raw-unit likelihoods differ by the scales' Jacobian.
    shift = -data.n_touches * np.log(scales).sum()
    assert b.log_likelihood == pytest.approx(a.log_likelihood + shift, abs=1e-4)


def test_correlated_fit_recovers_the_noise_correlation() -> None:
    world = correlated_noise_world(np.random.default_rng(6), n_objects=4, action_dim=1)
    data = sample_dataset(world, np.random.default_rng(7), 30)
    model = fit_manifold(
        data, 2, np.random.default_rng(0), FitOptions(restarts=0), noise_model="correlated"
    )
    assert model.transform is not None
    assert model.transform.kind == "correlated"
    truth = np.asarray(world.noise_correlation)
    assert np.abs(model.transform.correlation - truth).max() < 0.2
    np.testing.assert_array_equal(model.raw_data.observations, data.observations)
    first = fit_manifold(
        data, 2, np.random.default_rng(0), FitOptions(restarts=0), noise_model="independent"
    )
    again = correlated_transform(
        condition(transform_data(data, first.observation_transform), first.latents,
                  first.hyperparameters),
        standardising_transform(data),
    )  # fmt: skip
    np.testing.assert_allclose(again.correlation, model.transform.correlation, atol=1e-8)


def test_kronecker_inverse_diagonal_matches_the_dense_one() -> None:
    from core.evaluation.designs import collect, shared_design
    from core.evaluation.worlds import Experiment1World
    from core.gp.noise_model import gram_inverse_diagonal

    rng = np.random.default_rng(8)
    design = shared_design(4, 6, np.zeros(1), np.eye(1), rng)
    data = collect(Experiment1World(noise_std=0.1), design, rng)
    latents = np.array([[-1.0, 0.2], [0.0, 1.0], [0.5, -0.3], [1.0, 0.0]])
    kron = condition(data, latents, HYPER, structure="kronecker")
    dense = condition(data, latents, HYPER, structure="dense")
    assert kron.posterior.structure == "kronecker"
    got = gram_inverse_diagonal(kron)
    want = gram_inverse_diagonal(dense)
    assert got is not None
    assert want is not None
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert not kron.posterior.has_dense_inverse  # not materialised on the way
    loo_k, loo_d = loo_log_likelihoods(kron), loo_log_likelihoods(dense)
    assert loo_k is not None
    assert loo_d is not None
    np.testing.assert_allclose(loo_k, loo_d, rtol=1e-9)


def test_the_correlated_refit_is_one_warm_start_from_the_first_fit() -> None:
    world = correlated_noise_world(np.random.default_rng(6), n_objects=4, action_dim=1)
    data = sample_dataset(world, np.random.default_rng(9), 20)
    options = FitOptions(restarts=1)
    events = list(iter_fit(data, 2, np.random.default_rng(0), options, "correlated"))
    refit = [e for e in events if e.phase.startswith("correlated: ")]
    # One start, polished on all the data: no screening, no restarts.
    assert {e.n_starts for e in refit} == {1}
    assert {e.phase.partition(": ")[2].removesuffix(" done") for e in refit} == {"joint", "done"}
    model = events[-1].model
    assert model is not None
    assert model.transform is not None
    independent = fit_manifold(
        data, 2, np.random.default_rng(0), options, noise_model="independent"
    )
    first = condition(transform_data(data, independent.observation_transform),
                      independent.latents, independent.hyperparameters)  # fmt: skip
    start = warm_start(first, model.transform)
    whitened = transform_data(data, model.transform)
    at_start = condition(whitened, start.latents, start.hyperparameters).log_likelihood
    assert refit[-1].log_likelihood > at_start


def test_the_warm_start_carries_the_first_fit_through_the_whitening() -> None:
    data = raw_data()
    base = standardising_transform(data)
    first = condition(transform_data(data, base), LATENTS, HYPER)
    transform = correlated_transform(first, base)
    start = warm_start(first, transform)
    np.testing.assert_array_equal(start.latents, first.latents)
    np.testing.assert_array_equal(
        start.hyperparameters.latent_lengthscales, HYPER.latent_lengthscales
    )
    # Whitened noise has unit variance; each feature's signal is the mix W z of the first's.
    np.testing.assert_array_equal(start.hyperparameters.noise_variance, np.ones(3))
    w = transform.whitening
    np.testing.assert_allclose(
        start.hyperparameters.signal_variance, (w**2) @ HYPER.signal_variance, rtol=1e-12
    )
    residual_noise = (
        w
        @ (np.sqrt(np.outer(HYPER.noise_variance, HYPER.noise_variance)) * transform.correlation)
        @ w.T
    )
    np.testing.assert_allclose(np.diag(residual_noise), np.ones(3), rtol=1e-9)


@pytest.mark.parametrize("noise_model", ["independent", "auto"])
def test_the_fraction_done_grows_to_one(noise_model: NoiseModelChoice) -> None:
    world = correlated_noise_world(np.random.default_rng(6), n_objects=4, action_dim=1)
    data = sample_dataset(world, np.random.default_rng(7), 24)
    options = FitOptions(restarts=1, screen_touches_per_object=8)
    events = list(iter_fit(data, 2, np.random.default_rng(0), options, noise_model))
    fractions = [e.fraction for e in events]
    assert fractions[-1] == 1.0
    assert all(0.0 <= f <= 1.0 for f in fractions)
    assert fractions == sorted(fractions)
    assert len(set(fractions)) > 4  # it advances stage by stage, not only at the end
    # 1 only once the fit (a noise model's last stage) has ended.
    assert all(e.fraction < 1.0 for e in events if e.phase.split(": ")[-1] != "done")


def test_a_fit_already_done_is_continued_not_repeated() -> None:
    world = correlated_noise_world(np.random.default_rng(6), n_objects=4, action_dim=1)
    data = sample_dataset(world, np.random.default_rng(9), 20)
    options = FitOptions(restarts=1)
    whole = fit_manifold(data, 2, np.random.default_rng(0), options, noise_model="auto")
    first = fit_manifold(data, 2, np.random.default_rng(0), options, noise_model="independent")
    # "auto" from the independent fit: only the correlated refit runs, to the same model.
    events = list(iter_fit(data, 2, np.random.default_rng(5), options, "auto", fitted=first))
    assert not [e for e in events if e.phase.startswith("independent")]
    assert [e for e in events if e.phase.startswith("correlated: ")]
    model = events[-1].model
    assert model is not None
    assert model.log_likelihood == whole.log_likelihood
    np.testing.assert_array_equal(model.latents, whole.latents)
    assert model.transform is not None
    assert whole.transform is not None
    assert model.transform.note == whole.transform.note
    # "independent": the fit is the model; "correlated" from a correlated fit: likewise.
    [done] = list(iter_fit(data, 2, np.random.default_rng(5), options, "independent", fitted=first))
    assert done.model is not None
    assert done.model.log_likelihood == first.log_likelihood
    assert done.model.transform is not None
    assert first.transform is not None
    assert done.model.transform.note == first.transform.note
    correlated = fit_manifold(data, 2, np.random.default_rng(0), options, noise_model="correlated")
    [done] = list(
        iter_fit(data, 2, np.random.default_rng(5), options, "correlated", fitted=correlated)
    )
    assert done.model is correlated
    with pytest.raises(InvalidInputError, match="fitted"):
        iter_fit(data, 3, np.random.default_rng(5), options, "auto", fitted=first)
    with pytest.raises(InvalidInputError, match="fitted"):
        iter_fit(data, 2, np.random.default_rng(5), options, None, fitted=first)
    bare = fit_manifold(data, 2, np.random.default_rng(0), options)  # no transform
    with pytest.raises(InvalidInputError, match="fitted"):
        list(iter_fit(data, 2, np.random.default_rng(5), options, "auto", fitted=bare))
