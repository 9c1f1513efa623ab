"""The placement effect inside the fit: the likelihood and posterior with σ_b² in the training
covariance against the direct formula, its gradient against finite differences, the estimator
under such a model, and the rounds of :func:`core.gp.with_placement_effect`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.stats

from core.errors import InvalidInputError
from core.evaluation.worlds import sample_experiment1
from core.gp.fit_options import FitOptions
from core.gp.kernels import squared_exponential
from core.gp.likelihood import ManifoldLikelihood
from core.gp.manifold import refit_warm
from core.gp.placement_effect import estimate_placement_variance, with_placement_effect
from core.gp.placement_groups import add_shared_offsets, shared_groups
from core.gp.posterior import condition, gram_matrix, predict_model_space
from core.types import Hyperparameters, TrainingData


def _runs(touches: int, run: int, offset_std: float, seed: int) -> TrainingData:
    """Experiment 1 touches in runs of ``run`` at one placement, each run sharing an offset."""
    rng = np.random.default_rng(seed)
    base = sample_experiment1(rng, touches_per_object=touches, noise_std=0.1)
    placement = np.zeros(base.n_touches, dtype=np.int64)
    observations = base.observations.copy()
    for obj in range(base.n_objects):
        rows = np.flatnonzero(base.object_index == obj)
        placement[rows] = np.arange(rows.size) // run
        for p in np.unique(placement[rows]):
            observations[rows[placement[rows] == p]] += rng.normal(0.0, offset_std, size=3)
    # Shuffle the rows: the likelihood must not rely on the placements being contiguous.
    order = rng.permutation(base.n_touches)
    return TrainingData(
        base.object_names,
        base.object_index[order],
        base.actions[order],
        observations[order],
        placement[order],
    )


def _hyper(offset_std: float) -> Hyperparameters:
    return Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.full(3, 0.01 + offset_std**2),
        latent_lengthscales=np.array([[1.9], [3.0], [8.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )


LATENTS = np.array([[-1.3], [-0.4], [0.5], [1.2]])


def test_shared_offsets_are_the_indicator_product() -> None:
    object_index = np.array([0, 0, 1, 0, 1, 1])
    placement = np.array([0, 0, 0, 1, 0, 2])
    groups = shared_groups(object_index, placement)
    assert [g.tolist() for g in groups] == [[0, 1], [2, 4]]
    gram = np.zeros((6, 6))
    add_shared_offsets(gram, groups, 0.3)
    z = np.zeros((6, 4))
    for column, (obj, p) in enumerate([(0, 0), (1, 0), (0, 1), (1, 2)]):
        z[(object_index == obj) & (placement == p), column] = 1.0
    np.testing.assert_allclose(gram, 0.3 * (z @ z.T - np.eye(6)))
    assert shared_groups(object_index, None) == []


def test_likelihood_equals_the_direct_gaussian_with_shared_offsets() -> None:
    """The likelihood fits the within-placement noise σ_w²; its Gaussian is the posterior's,
    whose noise variance is each touch's whole σ_w² + σ_b²."""
    data = _runs(12, 3, 0.1, 0)
    within = _hyper(0.1)
    variance = np.array([0.006, 0.01, 0.0])
    whole = dataclasses.replace(within, noise_variance=within.noise_variance + variance)
    likelihood = ManifoldLikelihood(data, 1, placement_variance=variance)
    vector = likelihood.layout.pack(LATENTS, within)
    direct = 0.0
    for a in range(3):
        gram = gram_matrix(data, LATENTS, whole, a, variance)
        centred = data.observations[:, a] - data.observation_mean[a]
        direct -= scipy.stats.multivariate_normal(np.zeros(data.n_touches), gram).logpdf(centred)
    assert likelihood.value(vector) == pytest.approx(direct, rel=1e-10)
    value, _ = likelihood.value_and_gradient(vector)
    assert value == pytest.approx(direct, rel=1e-10)
    model = condition(data, LATENTS, whole, placement_variance=variance)
    assert model.log_likelihood == pytest.approx(-direct, rel=1e-10)
    assert model.placement_in_fit
    np.testing.assert_array_equal(model.placement_variance, variance)
    # Without the offsets the value differs (the test can fail) and σ_b² = 0 gives it back.
    plain = ManifoldLikelihood(data, 1).value(likelihood.layout.pack(LATENTS, whole))
    assert abs(plain - direct) > 1.0
    zero = ManifoldLikelihood(data, 1, placement_variance=np.zeros(3))
    assert zero.value(vector) == pytest.approx(ManifoldLikelihood(data, 1).value(vector), rel=1e-12)


def test_gradient_with_shared_offsets_matches_finite_differences() -> None:
    data = _runs(8, 3, 0.1, 1)
    likelihood = ManifoldLikelihood(data, 2, placement_variance=np.array([0.03, 0.01, 0.02]))
    rng = np.random.default_rng(2)
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.array([0.02, 0.03, 0.05]),
        latent_lengthscales=np.array([[1.9, 1.1], [3.0, 0.8], [1.5, 2.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )
    vector = likelihood.layout.pack(rng.normal(size=(4, 2)), hyper)
    _, gradient = likelihood.value_and_gradient(vector)
    step = 1e-6
    numeric = np.empty_like(vector)
    for i in range(vector.size):
        up, down = vector.copy(), vector.copy()
        up[i] += step
        down[i] -= step
        numeric[i] = (likelihood.value(up) - likelihood.value(down)) / (2 * step)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-5)


def test_posterior_predicts_as_the_direct_formula() -> None:
    data = _runs(10, 4, 0.1, 3)
    hyper = _hyper(0.1)
    variance = np.array([0.006, 0.004, 0.008])
    model = condition(data, LATENTS, hyper, placement_variance=variance)
    query_latents = np.array([[0.3], [-1.0]])
    query_actions = np.array([[0.2], [-1.5]])
    mean, var = predict_model_space(model, query_latents, query_actions)
    for a in range(3):
        gram = gram_matrix(data, LATENTS, hyper, a, variance)
        k_latent = squared_exponential(query_latents, LATENTS, hyper.latent_lengthscales[a])
        k_action = squared_exponential(query_actions, data.actions, hyper.action_lengthscales[a])
        cross = hyper.signal_variance[a] * k_latent[:, data.object_index] * k_action
        centred = data.observations[:, a] - data.observation_mean[a]
        expected_mean = data.observation_mean[a] + cross @ np.linalg.solve(gram, centred)
        reduction = np.sum(cross * np.linalg.solve(gram, cross.T).T, axis=1)
        expected_var = hyper.signal_variance[a] - reduction + hyper.noise_variance[a]
        np.testing.assert_allclose(mean[:, a], expected_mean, rtol=1e-9)
        np.testing.assert_allclose(var[:, a], expected_var, rtol=1e-9)


def test_bad_placement_effects_are_refused() -> None:
    data = _runs(6, 3, 0.1, 4)
    hyper = _hyper(0.1)
    with pytest.raises(InvalidInputError, match="placement_variance"):
        ManifoldLikelihood(data, 1, placement_variance=np.array([0.1, -1e-3, 0.2]))
    unplaced = dataclasses.replace(data, placement_index=None)
    with pytest.raises(InvalidInputError, match="record no placements"):
        ManifoldLikelihood(unplaced, 1, placement_variance=np.full(3, 0.002))
    with pytest.raises(InvalidInputError, match="record no placements"):
        condition(unplaced, LATENTS, hyper, placement_variance=np.full(3, 0.001))
    with pytest.raises(InvalidInputError, match=r"\[0, σ_n,a²\)"):
        condition(data, LATENTS, hyper, placement_variance=hyper.noise_variance)
    with pytest.raises(InvalidInputError, match="dense posterior"):
        condition(data, LATENTS, hyper, structure="sparse", placement_variance=np.full(3, 0.001))


@pytest.mark.parametrize("in_fit", [0.0, 0.005, 0.015])
def test_estimator_is_unbiased_whatever_the_variance_already_in_the_fit(in_fit: float) -> None:
    """σ_b² = 0.01 per feature in runs of 5; estimated from models conditioned with none, half
    of it, and one and a half times it in their training covariance."""
    data = _runs(100, 5, 0.1, 7)
    hyper = _hyper(0.1)
    model = condition(data, LATENTS, hyper, placement_variance=np.full(3, in_fit))
    assert data.placement_index is not None
    estimate = estimate_placement_variance(model, data.placement_index)
    assert estimate.groups == 80
    # 80 placements give a relative standard error of about 0.2.
    assert np.all(estimate.variance > 0.005)
    assert np.all(estimate.variance < 0.016)


def test_rounds_refit_with_the_effect_in_the_likelihood() -> None:
    data = _runs(40, 5, 0.15, 11)
    hyper = _hyper(0.15)
    start = condition(dataclasses.replace(data, placement_index=None), LATENTS, hyper)
    start = dataclasses.replace(start, data=data)  # the fit's data keep their placements
    options = FitOptions(max_iterations=60)
    assert data.placement_index is not None
    first = estimate_placement_variance(start, data.placement_index)
    refit = refit_warm(data, start, options, placement_variance=first.variance)
    assert refit.placement_in_fit
    np.testing.assert_array_equal(refit.placement_variance, first.variance)
    assert np.all(refit.hyperparameters.noise_variance > first.variance)
    # The refit climbs the likelihood with the effect from where the model stood.
    before = condition(data, start.latents, hyper, placement_variance=first.variance)
    assert refit.log_likelihood >= before.log_likelihood - 1e-6
    fitted, estimate = with_placement_effect(start, options, rounds=2)
    assert estimate is not None
    assert fitted.placement_in_fit
    np.testing.assert_array_equal(fitted.placement_variance, estimate.variance)
    # σ_b² = 0.0225 per feature.
    assert np.all(estimate.variance > 0.01)
    assert np.all(estimate.variance < 0.035)
    assert fitted.diagnostics is start.diagnostics
    with pytest.raises(InvalidInputError, match="rounds"):
        with_placement_effect(start, options, rounds=-1)


def test_the_rounds_are_not_bounded_by_the_fitted_noise() -> None:
    """A model whose σ_n² is far below the placements' offsets (σ_b² = 0.09, σ_n² = 0.02):
    split off σ_n² the estimate is clipped at 0.95 σ_n²; in the rounds it is not, and the
    refitted within-placement noise sits beside it."""
    data = _runs(60, 5, 0.3, 13)
    hyper = _hyper(0.1)
    assert data.placement_index is not None
    model = condition(data, LATENTS, hyper)
    clipped = estimate_placement_variance(model, data.placement_index)
    np.testing.assert_allclose(clipped.variance, 0.95 * hyper.noise_variance)
    free = estimate_placement_variance(model, data.placement_index, within_noise=False)
    assert np.all(free.variance > 0.05)
    np.testing.assert_array_equal(free.variance, np.maximum(free.raw_variance, 0.0))
    fitted, estimate = with_placement_effect(model, FitOptions(max_iterations=60), rounds=2)
    assert estimate is not None
    assert np.all(estimate.variance > 0.05)
    assert np.all(estimate.variance < 0.14)
    within = fitted.hyperparameters.noise_variance - fitted.placement_variance
    assert np.all(within > 0.0)
    assert np.all(within < 0.03)  # σ_w² = 0.01
    scored, split = with_placement_effect(model, rounds=0)
    assert split is not None
    assert not scored.placement_in_fit
    np.testing.assert_array_equal(scored.placement_variance, clipped.variance)
