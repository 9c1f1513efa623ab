"""σ_d²'s estimator (the drift shared by touches made close in time) and its use in recognition."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.worlds import EXPERIMENT1_THETAS, sample_experiment1
from core.gp.drift_effect import (
    check_drift_variance,
    default_window_s,
    estimate_drift_variance,
    with_drift_effect,
)
from core.gp.placement_effect import trial_log_likelihoods
from core.gp.posterior import condition
from core.recognition.object_posterior import (
    object_log_likelihoods,
    object_posterior,
    shared_variance,
)
from core.types import Hyperparameters, ManifoldModel, TrainingData

GAP_S = 10.0  # one touch every 10 s, in rounds over the 4 objects
BLOCK = 20  # the drift holds for 20 touches (200 s), then jumps to a fresh draw


def drifting_model(drift_std: float, seed: int) -> ManifoldModel:
    """Experiment 1, 100 touches per object made in rounds over the objects, every feature
    shifted by a drift common to all objects that holds for :data:`BLOCK` touches."""
    rng = np.random.default_rng(seed)
    base = sample_experiment1(rng, touches_per_object=100, noise_std=0.1)
    order = np.argsort(
        [np.flatnonzero(base.object_index[: i + 1] == base.object_index[i]).size * 10 + o
         for i, o in enumerate(base.object_index)]
    )  # fmt: skip
    times = np.empty(base.n_touches)
    times[order] = GAP_S * np.arange(base.n_touches)
    drift = rng.normal(0.0, drift_std, size=(base.n_touches // BLOCK + 1, 3))
    block = (times / GAP_S).astype(int) // BLOCK
    observations = base.observations + drift[block]
    data = TrainingData(
        base.object_names, base.object_index, base.actions, observations, touch_times_s=times
    )
    theta = np.asarray(EXPERIMENT1_THETAS)[:, None]
    centred = theta - theta.mean()
    hyper = Hyperparameters(
        signal_variance=np.array([0.18, 0.2, 0.27]),
        noise_variance=np.full(3, 0.01 + drift_std**2),
        latent_lengthscales=np.array([[1.9], [100.0], [8.0]]),
        action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
    )
    return condition(data, centred / np.sqrt(np.mean(centred**2)), hyper)


def test_the_window_is_five_gaps_of_the_collection() -> None:
    times = np.array([30.0, 0.0, 10.0, 20.0, 20.0, 45.0])
    assert default_window_s(times) == pytest.approx(5 * 10.0)
    with pytest.raises(InvalidInputError, match="different times"):
        default_window_s(np.zeros(4))


@pytest.fixture(scope="module")
def drifting() -> ManifoldModel:
    return drifting_model(0.1, 1)


def test_estimator_recovers_the_drift_variance(drifting: ManifoldModel) -> None:
    model = drifting
    times = model.data.touch_times_s
    assert times is not None
    estimate = estimate_drift_variance(model, times)
    assert estimate.window_s == pytest.approx(5 * GAP_S)
    # Every touch pairs with the touches of other objects within 50 s: 5 later ones, less
    # the few of its own object (1 in 4 of them).
    assert 0.7 * 5 * 400 < estimate.pairs < 5 * 400
    # σ_d² = 0.01; pairs within 50 s share a 200 s block about 85 % of the time.
    assert np.all(estimate.variance > 0.005)
    assert np.all(estimate.variance < 0.013)


def test_estimator_finds_no_drift_without_one() -> None:
    model = drifting_model(0.0, 2)
    assert model.data.touch_times_s is not None
    estimate = estimate_drift_variance(model, model.data.touch_times_s)
    assert np.all(np.abs(estimate.raw_variance) < 0.002)


def test_touches_far_apart_give_no_pairs_and_no_effect(drifting: ManifoldModel) -> None:
    model = drifting
    assert model.data.touch_times_s is not None
    estimate = estimate_drift_variance(model, model.data.touch_times_s, window_s=GAP_S / 2)
    assert estimate.pairs == 0
    assert np.array_equal(estimate.variance, np.zeros(3))


def test_the_estimate_leaves_the_touch_its_own_noise(drifting: ManifoldModel) -> None:
    """σ_d² is clipped so that σ_b² + σ_d² stays at or below 0.95 σ_n²."""
    noise = drifting.hyperparameters.noise_variance
    placed = dataclasses.replace(drifting, placement_variance=0.9 * noise)
    assert drifting.data.touch_times_s is not None
    estimate = estimate_drift_variance(placed, drifting.data.touch_times_s)
    assert np.all(estimate.raw_variance > 0.05 * noise)
    np.testing.assert_allclose(estimate.variance, 0.05 * noise)


def test_bad_times_are_named(drifting: ManifoldModel) -> None:
    model = drifting
    with pytest.raises(InvalidInputError, match="touch_times_s"):
        estimate_drift_variance(model, np.zeros(3))
    with pytest.raises(InvalidInputError, match="window_s"):
        estimate_drift_variance(model, np.arange(400.0), window_s=-1.0)
    with pytest.raises(InvalidInputError, match="touch_times_s"):
        TrainingData(
            model.data.object_names,
            model.data.object_index,
            model.data.actions,
            model.data.observations,
            touch_times_s=np.full(400, np.nan),
        )


def test_recognition_counts_the_drift_once_whatever_the_placement(drifting: ManifoldModel) -> None:
    """A trial's touches are scored jointly with σ_d² shared (and σ_b² too when they met one
    placement): the same as the joint likelihood with that shared variance."""
    rng = np.random.default_rng(6)
    x = rng.normal(size=(4, 1))
    y = drifting.data.observations[:4] + 0.05
    noise = drifting.hyperparameters.noise_variance
    both = dataclasses.replace(drifting, placement_variance=0.3 * noise, drift_variance=0.4 * noise)
    np.testing.assert_array_equal(shared_variance(both), 0.7 * noise)
    np.testing.assert_array_equal(shared_variance(both, shared_placement=False), 0.4 * noise)
    np.testing.assert_array_equal(shared_variance(drifting), np.zeros(3))
    for shared, variance in ((True, 0.7 * noise), (False, 0.4 * noise)):
        np.testing.assert_allclose(
            object_log_likelihoods(both, x, y, shared_placement=shared),
            trial_log_likelihoods(both, x, y, variance),
            rtol=1e-12,
        )
    # A model without a drift variance scores as before.
    assert not np.allclose(object_posterior(both, x, y), object_posterior(drifting, x, y))


def test_with_drift_effect_needs_times(drifting: ManifoldModel) -> None:
    fitted, estimate = with_drift_effect(drifting)
    assert estimate is not None
    assert fitted.drift_variance is not None
    np.testing.assert_array_equal(fitted.drift_variance, estimate.variance)
    untimed = dataclasses.replace(
        drifting, data=dataclasses.replace(drifting.data, touch_times_s=None)
    )
    unchanged, nothing = with_drift_effect(untimed)
    assert unchanged is untimed
    assert nothing is None


def test_check_drift_variance_leaves_the_touch_its_own_noise(drifting: ManifoldModel) -> None:
    noise = drifting.hyperparameters.noise_variance
    placed = dataclasses.replace(drifting, placement_variance=0.5 * noise)
    np.testing.assert_array_equal(check_drift_variance(placed, 0.4 * noise), 0.4 * noise)
    with pytest.raises(InvalidInputError, match="drift_variance"):
        check_drift_variance(placed, 0.5 * noise)
    with pytest.raises(InvalidInputError, match="drift_variance"):
        check_drift_variance(drifting, -0.1 * noise)
    with pytest.raises(InvalidInputError, match="drift_variance"):
        check_drift_variance(drifting, noise[:2])
