"""The placement oracle's covariance (bench.placement_oracle): hand values, and a trial score that
is the model's own when the slopes are zero and falls with a slope the touches contradict."""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.placement_oracle import oracle_log_likelihoods, placement_covariance
from core.recognition.object_posterior import object_log_likelihoods
from tests.core.test_input_shift import two_action_model


def test_the_placement_covariance_against_hand_values() -> None:
    slopes = np.array([[1.0, 2.0], [3.0, -1.0]])  # (T = 2, dy = 2)
    cov = placement_covariance(slopes, placement_std=0.5, slip_std=0.2)
    # Feature-major order (a0 t0, a0 t1, a1 t0, a1 t1); angle covariance [[.25, .25], [.25, .29]].
    g = np.array([1.0, 3.0, 2.0, -1.0])
    angle = np.array([[0.25, 0.25], [0.25, 0.29]])
    expected = np.outer(g, g) * np.tile(angle, (2, 2))
    np.testing.assert_allclose(cov, expected)
    assert np.isclose(cov[1, 3], 3.0 * -1.0 * 0.29)  # touch 1, across features: one slip


def test_zero_slopes_give_the_model_score_and_a_slope_changes_it() -> None:
    model = two_action_model()
    placed = dataclasses.replace(model, placement_variance=np.array([0.004, 0.008]))
    rng = np.random.default_rng(3)
    x = rng.normal(size=(4, 2))
    y = rng.normal(size=(4, 2))
    zero = [np.zeros((4, 2))] * 3
    np.testing.assert_allclose(
        oracle_log_likelihoods(placed, x, y, zero, keep_shift=True),
        object_log_likelihoods(placed, x, y),
        rtol=1e-10,
    )
    steep = [np.full((4, 2), 5.0)] * 3
    assert np.all(
        oracle_log_likelihoods(placed, x, y, steep, keep_shift=True)
        != object_log_likelihoods(placed, x, y)
    )
