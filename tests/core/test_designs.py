"""Collection designs: the paper's random design and the shared (Kronecker) design."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.evaluation.designs import collect, random_design, shared_design, sobol_normal_actions
from core.evaluation.worlds import Experiment1World, random_experiment2_world
from core.gp.kronecker import find_shared_design

MEAN = np.array([0.5, -1.0])
COV = np.array([[2.0, 0.6], [0.6, 1.0]])


def test_sobol_actions_follow_the_action_prior() -> None:
    actions = sobol_normal_actions(1024, MEAN, COV, np.random.default_rng(0))
    assert actions.shape == (1024, 2)
    # A balanced scrambled Sobol set reproduces the moments far better than 1024 random draws
    # (whose standard error on the mean is ~0.04).
    np.testing.assert_allclose(actions.mean(axis=0), MEAN, atol=0.01)
    np.testing.assert_allclose(np.cov(actions, rowvar=False), COV, atol=0.03)
    again = sobol_normal_actions(1024, MEAN, COV, np.random.default_rng(0))
    np.testing.assert_array_equal(actions, again)


def test_sobol_actions_work_with_a_singular_prior_and_one_action() -> None:
    singular = np.array([[1.0, 1.0], [1.0, 1.0]])
    actions = sobol_normal_actions(64, np.zeros(2), singular, np.random.default_rng(1))
    np.testing.assert_allclose(actions[:, 0], actions[:, 1], atol=1e-12)
    assert sobol_normal_actions(1, MEAN, COV, np.random.default_rng(2)).shape == (1, 2)


def test_shared_design_touches_every_object_with_the_same_actions() -> None:
    design = shared_design(5, 16, MEAN, COV, np.random.default_rng(3))
    assert design.shared
    assert design.n_touches == 80
    per_object = design.actions.reshape(5, 16, 2)
    for obj in range(1, 5):
        np.testing.assert_array_equal(per_object[obj], per_object[0])
    np.testing.assert_array_equal(design.object_index, np.repeat(np.arange(5), 16))


def test_random_design_draws_a_fresh_action_per_touch() -> None:
    design = random_design(4, 2000, MEAN, COV, np.random.default_rng(4))
    assert not design.shared
    assert design.actions.shape == (8000, 2)
    assert np.unique(design.actions[:, 0]).size == 8000
    np.testing.assert_allclose(design.actions.mean(axis=0), MEAN, atol=0.05)
    np.testing.assert_allclose(np.cov(design.actions, rowvar=False), COV, atol=0.1)


def test_collect_with_a_shared_design_gives_kronecker_data() -> None:
    rng = np.random.default_rng(5)
    world = random_experiment2_world(rng, n_objects=3)
    design = shared_design(3, 8, world.action_mean, world.action_cov, rng)
    data = collect(world, design, rng)
    assert data.object_names == world.object_names
    assert data.n_touches == 24
    found = find_shared_design(data)
    assert found is not None
    assert found.size == 8
    noise_free = world.mean_response(1, design.actions[8:16])
    residual = data.observations[8:16] - noise_free
    assert np.std(residual) == pytest.approx(0.05, rel=0.5)
    random = collect(world, random_design(3, 8, world.action_mean, world.action_cov, rng), rng)
    assert find_shared_design(random) is None


def test_bad_designs_are_rejected() -> None:
    rng = np.random.default_rng(6)
    with pytest.raises(InvalidInputError, match="n_objects"):
        shared_design(1, 4, MEAN, COV, rng)
    with pytest.raises(InvalidInputError, match="n_actions"):
        shared_design(3, 1, MEAN, COV, rng)
    with pytest.raises(InvalidInputError, match="touches_per_object"):
        random_design(3, 1, MEAN, COV, rng)
    with pytest.raises(InvalidInputError, match="symmetric"):
        sobol_normal_actions(4, MEAN, np.array([[1.0, 0.5], [0.0, 1.0]]), rng)
    with pytest.raises(InvalidInputError, match="positive semi-definite"):
        sobol_normal_actions(4, MEAN, np.diag([1.0, -1.0]), rng)
    with pytest.raises(InvalidInputError, match="action cov: expected shape"):
        sobol_normal_actions(4, MEAN, np.eye(3), rng)
    with pytest.raises(InvalidInputError, match="dx=2, the world has dx=1"):
        collect(Experiment1World(), shared_design(4, 3, MEAN, COV, rng), rng)
    with pytest.raises(InvalidInputError, match="touches object 5"):
        collect(Experiment1World(), shared_design(6, 3, np.zeros(1), np.eye(1), rng), rng)
