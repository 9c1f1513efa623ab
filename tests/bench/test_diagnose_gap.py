"""The pure statistics of bench/diagnose_gap.py against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from bench.diagnose_gap import (
    action_distance,
    design_effect,
    intraclass_correlation,
    standardised_residuals,
    summarise,
)
from core.evaluation.reference_model import experiment1_at_true_latents
from core.evaluation.trial_engine import ModelSamples, WorldTouches
from core.recognition.object_posterior import touch_log_likelihoods


def test_icc_balanced_by_hand() -> None:
    # Means 2 and 6 (grand 4): MSB = 2·4 + 2·4 = 16, MSW = 4 / 2 = 2, n0 = 2,
    # σ_b² = (16 − 2) / 2 = 7, ICC = 7 / 9.
    assert intraclass_correlation([1, 3, 5, 7], ["a", "a", "b", "b"]) == pytest.approx(7 / 9)


def test_icc_unbalanced_by_hand() -> None:
    # Means 1 and 4 (grand 2): MSB = 2·1 + 1·4 = 6, MSW = 2 / 1 = 2, n0 = (3 − 5/3) / 1 = 4/3,
    # σ_b² = 4 / (4/3) = 3, ICC = 3 / 5.
    assert intraclass_correlation([0, 2, 4], [0, 0, 1]) == pytest.approx(0.6)


def test_icc_negative_when_groups_agree_more_than_chance() -> None:
    # Equal group means: MSB = 0, MSW = 5, σ_b² = −2.5, ICC = −1.
    assert intraclass_correlation([0, 4, 1, 3], [0, 0, 1, 1]) == pytest.approx(-1.0)


def test_icc_undefined_without_groups_or_replicates() -> None:
    assert np.isnan(intraclass_correlation([1, 2, 3], [0, 0, 0]))
    assert np.isnan(intraclass_correlation([1, 2], [0, 1]))
    with pytest.raises(ValueError, match="values and groups"):
        intraclass_correlation([1, 2, 3], [0, 1])


def test_icc_recovers_a_simulated_random_effect() -> None:
    rng = np.random.default_rng(0)
    groups, size, rho = 2000, 6, 0.4
    effect = np.repeat(rng.normal(0, np.sqrt(rho), groups), size)
    values = effect + rng.normal(0, np.sqrt(1 - rho), groups * size)
    assert intraclass_correlation(values, np.repeat(np.arange(groups), size)) == pytest.approx(
        rho, abs=0.03
    )


def test_design_effect() -> None:
    assert design_effect(0.5, 6) == pytest.approx(3.5)
    assert design_effect(0.0, 6) == pytest.approx(1.0)


def test_action_distance_by_hand() -> None:
    # Mean 0, covariance diag(4/3, 4/3) (ddof 1): x = (2, 0) → √(4 · 3/4 / 2) = √1.5.
    train = np.array([[-1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [1.0, -1.0]])
    d = action_distance(np.array([[2.0, 0.0], [0.0, 0.0]]), train)
    np.testing.assert_allclose(d, [np.sqrt(1.5), 0.0])


def test_residuals_of_the_models_own_draws_are_standard_normal() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=10)
    rng = np.random.default_rng(1)
    n = 400
    objects = rng.integers(0, len(model.object_names), n)
    actions = rng.normal(0, 1, (n, model.hyperparameters.action_dim))
    raw = np.array(
        [
            WorldTouches(ModelSamples(model), model.object_names[o]).touch(a, rng).observation
            for o, a in zip(objects, actions, strict=True)
        ]
    )
    z, log_density, epistemic = standardised_residuals(model, objects, actions, raw)
    assert z.shape == raw.shape
    assert epistemic.shape == raw.shape
    np.testing.assert_allclose(log_density, touch_log_likelihoods(model, objects, actions, raw))
    assert np.all((epistemic >= 0) & (epistemic < 1))
    # E[z²] = 1 within sampling error (sd of a mean of 400 χ²₁ ≈ 0.07).
    np.testing.assert_allclose((z**2).mean(axis=0), 1.0, atol=0.25)
    summary = summarise(model, objects, actions, raw, groups=np.arange(n) // 5)
    assert summary.touches == n
    assert abs(float(np.nanmean(summary.icc))) < 0.1


def test_a_shifted_observation_shows_as_a_biased_residual() -> None:
    model = experiment1_at_true_latents(seed=0, touches_per_object=10)
    objects = np.zeros(50, dtype=np.int64)
    actions = np.zeros((50, model.hyperparameters.action_dim))
    rng = np.random.default_rng(2)
    touches = WorldTouches(ModelSamples(model), model.object_names[0])
    raw = np.array([touches.touch(a, rng).observation for a in actions])
    z0, _, _ = standardised_residuals(model, objects, actions, raw)
    z1, _, _ = standardised_residuals(model, objects, actions, raw + 1.0)
    assert np.all(z1.mean(axis=0) > z0.mean(axis=0) + 1.0)
