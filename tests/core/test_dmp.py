"""Dynamic Movement Primitives (core/recognition/dmp.py): fit, reproduction, action offsets,
validation."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.recognition.dmp import (
    DMP,
    DMPGains,
    action_space,
    basis_responses,
    fit_dmp,
    rollout,
    trajectory_for_action,
    weights_for_action,
)

DT = 0.02
DURATION = 14.4


def smooth_step(u: np.ndarray, start: float, end: float) -> np.ndarray:
    z = np.clip((u - start) / (end - start), 0.0, 1.0)
    return z**3 * (10 - 15 * z + 6 * z**2)


def teaching() -> np.ndarray:
    """A press-slide-release demonstration in degrees (like the rig's, rebuilt here so core
    tests do not import hardware). Shape (721, 2)."""
    u = np.linspace(0.0, 1.0, round(DURATION / DT) + 1)
    flexion = 24.0 * (smooth_step(u, 0.02, 0.2) - smooth_step(u, 0.82, 0.97))
    flexion += 1.5 * (smooth_step(u, 0.3, 0.5) - smooth_step(u, 0.55, 0.75))
    abduction = 8.0 * (
        -smooth_step(u, 0.05, 0.2) + 2 * smooth_step(u, 0.25, 0.8) - smooth_step(u, 0.85, 0.98)
    )
    return np.stack([flexion, abduction], axis=1)


@pytest.fixture(scope="module")
def fitted() -> DMP:
    return fit_dmp(teaching(), DT, n_basis=25)


def test_reproduces_the_teaching_trajectory_at_zero_action(fitted: DMP) -> None:
    demo = teaching()
    reproduced = rollout(fitted)
    assert reproduced.shape == demo.shape
    # Tolerance: 1% of each joint's range (25 bases over 14.4 s).
    ranges = demo.max(axis=0) - demo.min(axis=0)
    assert np.all(np.abs(reproduced - demo).max(axis=0) < 0.01 * ranges)
    space = action_space(fitted)
    np.testing.assert_allclose(trajectory_for_action(space, np.zeros(6)), reproduced, atol=1e-9)


def test_paper_dimensions(fitted: DMP) -> None:
    assert fitted.weights.shape == (2, 25)
    space = action_space(fitted, n_dominant=3)
    assert space.action_dim == 6
    assert space.dominant.shape == (2, 3)
    assert np.all(np.diff(space.dominant, axis=1) > 0)


def test_dominant_weights_contribute_most(fitted: DMP) -> None:
    space = action_space(fitted)
    peak = np.abs(basis_responses(fitted).from_weights).max(axis=0)
    contribution = np.abs(fitted.weights) * peak
    for joint in range(2):
        chosen = contribution[joint, space.dominant[joint]]
        others = np.delete(contribution[joint], space.dominant[joint])
        assert chosen.min() >= others.max()


def test_one_unit_of_action_moves_the_trajectory_by_the_stated_amount(fitted: DMP) -> None:
    space = action_space(fitted, offset_deg_per_unit=2.0)
    base = trajectory_for_action(space, np.zeros(6))
    for component in range(6):
        x = np.zeros(6)
        x[component] = 1.0
        change = trajectory_for_action(space, x) - base
        joint = component // 3
        assert np.abs(change[:, joint]).max() == pytest.approx(2.0, rel=1e-9)
        assert np.abs(change[:, 1 - joint]).max() < 1e-12  # the other joint is untouched
    # The map from x to the trajectory is affine.
    x1, x2 = np.arange(6.0) / 5, -np.ones(6)
    combined = trajectory_for_action(space, x1 + x2) - base
    separate = (trajectory_for_action(space, x1) - base) + (trajectory_for_action(space, x2) - base)
    np.testing.assert_allclose(combined, separate, atol=1e-9)


def test_weights_for_action_offsets_only_the_dominant_ones(fitted: DMP) -> None:
    space = action_space(fitted)
    x = np.array([1.0, -2.0, 0.5, 0.0, 3.0, -1.0])
    weights = weights_for_action(space, x)
    changed = np.argwhere(~np.isclose(weights, fitted.weights))
    expected = {(j, int(i)) for j in range(2) for i in space.dominant[j]}
    expected.discard((1, int(space.dominant[1, 0])))  # x[3] = 0
    assert {(int(a), int(b)) for a, b in changed} == expected


def test_time_scaling_and_resampling(fitted: DMP) -> None:
    half = rollout(fitted, duration_s=DURATION / 2)
    assert half.shape == (361, 2)
    np.testing.assert_allclose(half, rollout(fitted)[::2], atol=1e-3)  # integration error
    coarse = rollout(fitted, dt_s=0.04)
    assert coarse.shape == (361, 2)
    np.testing.assert_allclose(coarse, rollout(fitted)[::2], atol=0.02)


def test_fitting_a_dmp_trajectory_recovers_it() -> None:
    truth = fit_dmp(teaching(), DT)
    regenerated = rollout(truth)
    refit = fit_dmp(regenerated, DT)
    np.testing.assert_allclose(rollout(refit), regenerated, atol=0.05)


def test_gains_and_inputs_are_validated() -> None:
    demo = teaching()
    with pytest.raises(InvalidInputError, match=r"expected shape \(any, any\)"):
        fit_dmp(demo[:, 0], DT)
    with pytest.raises(InvalidInputError, match="at least 75 samples"):
        fit_dmp(demo[:50], DT)
    with pytest.raises(InvalidInputError, match="dt_s"):
        fit_dmp(demo, 0.0)
    bad = demo.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InvalidInputError, match="non-finite"):
        fit_dmp(bad, DT)
    with pytest.raises(InvalidInputError, match="alpha_z"):
        DMPGains(alpha_z=-1.0)
    space = action_space(fit_dmp(demo, DT))
    with pytest.raises(InvalidInputError, match=r"action: expected shape \(6\)"):
        trajectory_for_action(space, np.zeros(5))
    with pytest.raises(InvalidInputError, match="n_dominant"):
        action_space(space.dmp, n_dominant=26)
