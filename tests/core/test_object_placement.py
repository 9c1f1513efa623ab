"""Each object's own placement variance: its estimator against the pooled one and the shrinkage
formula by hand, its use in the trial likelihood and the model world, and its checks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.trial_engine import ModelTrial
from core.gp import FitOptions
from core.gp.object_placement import (
    check_object_placement_variance,
    estimate_object_placement_variance,
    object_placement_ceiling,
    with_object_placement,
)
from core.gp.placement_effect import (
    estimate_placement_variance,
    placement_moments,
    trial_log_likelihoods,
)
from core.recognition import calibrate, with_latent_uncertainty
from core.recognition.latent_uncertainty import trial_log_likelihoods as latent_trials
from core.recognition.object_posterior import object_log_likelihoods
from core.types import ManifoldModel
from tests.core.test_placement_effect import placed_experiment1

#: The offset's standard deviation per placement of each of Experiment 1's four objects.
OFFSET_STD = (0.02, 0.02, 0.15, 0.15)


def _placed(seed: int, offset_std: tuple[float, ...] = OFFSET_STD) -> ManifoldModel:
    """Experiment 1 in placements of 4 whose offsets' spread depends on the object, with the
    pooled σ_b² in the model, as the fit would leave it."""
    model, placement = placed_experiment1(offset_std, seed, run=4)
    pooled = estimate_placement_variance(model, placement)
    return dataclasses.replace(model, placement_variance=pooled.variance)


@pytest.fixture(scope="module")
def placed() -> ManifoldModel:
    return _placed(3)


def test_each_object_has_the_pooled_estimator_on_its_own_placements(
    placed: ManifoldModel,
) -> None:
    placement = placed.raw_data.placement_index
    assert placement is not None
    estimate = estimate_object_placement_variance(placed, placement)
    assert estimate is not None
    big = int(placement.max()) + 1
    for obj in range(placed.data.n_objects):
        # The other objects' touches each on a placement of their own: no pairs of theirs.
        own = placement.copy()
        others = placed.data.object_index != obj
        own[others] = big + np.arange(int(others.sum()))
        alone = estimate_placement_variance(placed, own, within_noise=False)
        np.testing.assert_allclose(estimate.raw_variance[obj], alone.raw_variance, rtol=1e-10)
    assert np.all(estimate.placements == 25)


def test_shrinkage_is_the_formula_by_hand(placed: ManifoldModel) -> None:
    placement = placed.raw_data.placement_index
    assert placement is not None
    estimate = estimate_object_placement_variance(placed, placement)
    assert estimate is not None
    moments = placement_moments(placed, placement)
    raw, error = estimate.raw_variance, estimate.standard_error
    for obj in range(placed.data.n_objects):
        terms = moments.contributions[moments.objects == obj]
        pairs = moments.pairs[moments.objects == obj].astype(float)
        mean = terms.sum(axis=0) / pairs.sum()
        m = terms.shape[0]
        by_hand = (
            np.sqrt(m / (m - 1) * ((terms - pairs[:, None] * mean) ** 2).sum(axis=0)) / pairs.sum()
        )
        np.testing.assert_allclose(error[obj], by_hand, rtol=1e-12)
    tau = np.maximum(0.0, raw.var(axis=0, ddof=1) - (error**2).mean(axis=0))
    np.testing.assert_allclose(estimate.between_variance, tau, rtol=1e-12)
    assert placed.placement_variance is not None
    np.testing.assert_array_equal(estimate.mean, placed.placement_variance)
    shrunk = estimate.mean + tau / (tau + error**2) * (raw - estimate.mean)
    expected = np.clip(shrunk, 0.0, object_placement_ceiling(placed, estimate.mean))
    np.testing.assert_allclose(estimate.variance, expected, rtol=1e-12)


def test_objects_that_shift_more_get_more(placed: ManifoldModel) -> None:
    placement = placed.raw_data.placement_index
    assert placement is not None
    estimate = estimate_object_placement_variance(placed, placement)
    assert estimate is not None
    # True σ_b² 0.0004 on objects 0, 1 and 0.0225 on 2, 3 (every feature).
    assert np.all(estimate.between_variance > 0)
    assert np.all(estimate.variance[:2] < 0.01)
    assert np.all(estimate.variance[2:] > 0.012)
    assert placed.placement_variance is not None
    # Each lies between its own estimate and the pooled one.
    low = np.minimum(estimate.raw_variance, estimate.mean)
    high = np.maximum(estimate.raw_variance, estimate.mean)
    assert np.all((estimate.variance >= low - 1e-12) & (estimate.variance <= high + 1e-12))


def test_objects_alike_keep_the_pooled_value() -> None:
    alike = _placed(4, (0.08,) * 4)
    placement = alike.raw_data.placement_index
    assert placement is not None
    estimate = estimate_object_placement_variance(alike, placement)
    assert estimate is not None
    # No spread beyond the sampling noise on most features; where τ² > 0 it is small.
    weight = estimate.between_variance / (estimate.between_variance + estimate.standard_error**2)
    assert np.mean(weight < 0.5) > 0.5
    assert alike.placement_variance is not None
    np.testing.assert_allclose(estimate.variance.mean(axis=0), alike.placement_variance, rtol=0.5)


def test_trial_likelihood_takes_each_objects_row(placed: ManifoldModel) -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=(4, 1))
    y = rng.normal(size=(4, 3)) * 0.3
    rows = np.array([[0.001, 0.002, 0.0], [0.01, 0.0, 0.005], [0.02, 0.02, 0.02], [0.0] * 3])
    together = trial_log_likelihoods(placed, x, y, rows)
    laplace, _ = with_latent_uncertainty(placed)
    assert laplace.latent_covariance is not None
    with_latents = latent_trials(placed, x, y, rows, laplace.latent_covariance)
    for obj in range(4):
        assert together[obj] == pytest.approx(trial_log_likelihoods(placed, x, y, rows[obj])[obj])
        assert with_latents[obj] == pytest.approx(
            latent_trials(placed, x, y, rows[obj], laplace.latent_covariance)[obj]
        )
    # The model's own rows are what the object likelihood scores a shared placement with.
    by_object = dataclasses.replace(placed, object_placement_variance=rows)
    np.testing.assert_allclose(
        object_log_likelihoods(by_object, x, y, "joint"), together, rtol=1e-12
    )
    # Touches on placements of their own share nothing: the rows do not apply.
    np.testing.assert_allclose(
        object_log_likelihoods(by_object, x, y, "joint", shared_placement=False),
        object_log_likelihoods(placed, x, y, "joint", shared_placement=False),
        rtol=1e-12,
    )


def test_the_model_world_draws_the_targets_own_offset(placed: ManifoldModel) -> None:
    rows = np.zeros((4, 3))
    rows[2] = 0.02
    by_object = dataclasses.replace(placed, object_placement_variance=rows)
    x = np.zeros(1)
    for target, expected in ((0, 0.0), (2, 0.02)):
        name = placed.object_names[target]
        pairs = []
        for seed in range(1500):
            rng = np.random.default_rng(seed)
            trial = ModelTrial(by_object, name)
            pairs.append([trial.touch(x, rng).observation for _ in range(2)])
        draws = np.asarray(pairs)  # (trials, 2, dy)
        shared = np.mean(
            (draws[:, 0] - draws[:, 0].mean(0)) * (draws[:, 1] - draws[:, 1].mean(0)), axis=0
        )
        # The covariance of two touches of one placement is the offset's variance (the GP's
        # draws at one action are independent noise around one mean); ±4 standard errors.
        assert np.all(np.abs(shared - expected) < 4 * 0.03 / np.sqrt(1500) + 0.1 * expected)


def test_with_object_placement_needs_placements_and_a_pooled_effect(
    placed: ManifoldModel,
) -> None:
    fitted, estimate = with_object_placement(placed)
    assert estimate is not None
    np.testing.assert_array_equal(fitted.object_placement_variance, estimate.variance)
    no_pooled = dataclasses.replace(placed, placement_variance=None)
    assert with_object_placement(no_pooled) == (no_pooled, None)


def test_calibrate_adds_it_only_when_asked(placed: ManifoldModel) -> None:
    options = FitOptions()
    # The placement step refits; the fixture is a conditioned model at the true latents, so
    # start from it without the pooled value, as a fit would.
    raw = dataclasses.replace(placed, placement_variance=None)
    calibrated, found = calibrate(
        raw, options, np.random.default_rng(0), latent_uncertainty=False, object_placement=True
    )
    assert found.object_placement is not None
    np.testing.assert_array_equal(
        calibrated.object_placement_variance, found.object_placement.variance
    )
    without, none = calibrate(raw, options, np.random.default_rng(0), latent_uncertainty=False)
    assert without.object_placement_variance is None
    assert none.object_placement is None


def test_bad_rows_are_refused(placed: ManifoldModel) -> None:
    with pytest.raises(InvalidInputError, match="placement_index"):
        estimate_object_placement_variance(placed, np.zeros(3, dtype=np.int64))
    with pytest.raises(InvalidInputError, match="placement_index"):
        estimate_object_placement_variance(placed, np.zeros(placed.data.n_touches))
    assert placed.placement_variance is not None
    noise = placed.hyperparameters.noise_variance
    with pytest.raises(InvalidInputError, match="object_placement_variance"):
        check_object_placement_variance(placed, np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="σ_b,l,a²"):
        check_object_placement_variance(placed, np.tile(noise, (4, 1)))
    with pytest.raises(InvalidInputError, match="σ_b,l,a²"):
        check_object_placement_variance(placed, -np.ones((4, 3)))
    with pytest.raises(InvalidInputError, match="no pooled placement effect"):
        check_object_placement_variance(
            dataclasses.replace(placed, placement_variance=None), np.zeros((4, 3))
        )
