"""The Kronecker gradient (block sums through P_s = U_s C̃ and P_x = U_x C̃ᵀ, one triangle from
symmetric rank-k updates) matches the dense path where its sign handling matters: singular
latent and action Gram matrices (coincident objects, a repeated design action: eigenvalues at
round-off below zero), with L > M and L < M."""

from __future__ import annotations

import numpy as np
import pytest

from core.evaluation.designs import collect, shared_design
from core.evaluation.worlds import random_experiment2_world
from core.gp.kronecker import condition_kronecker
from core.gp.posterior import condition
from core.types import Hyperparameters, TrainingData
from tests.core.agreement import assert_kronecker_matches_dense

TOLERANCE = 1e-8


def singular_problem(
    n_objects: int, n_actions: int, seed: int
) -> tuple[TrainingData, np.ndarray, Hyperparameters]:
    """A shared design whose design action 1 repeats action 0 (K^x singular) and whose objects
    0, 1 coincide and 2 nearly does (K^s singular: a zero eigenvalue, computed at ±1e-16)."""
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(
        rng, n_objects=n_objects, latent_dim=2, action_dim=2, observation_dim=2
    )
    plan = shared_design(n_objects, n_actions, np.zeros(2), np.eye(2), rng)
    data = collect(world, plan, rng)
    actions = data.actions.copy()  # object-major, design order
    actions[1::n_actions] = actions[::n_actions]  # design action 1 repeats action 0
    data = TrainingData(data.object_names, data.object_index, actions, data.observations)
    latents = rng.standard_normal((n_objects, 2))
    latents[1] = latents[0]
    latents[2] = latents[0] + 1e-9
    hyper = Hyperparameters(
        signal_variance=np.array([1.3, 0.6]),
        noise_variance=np.array([0.05, 0.01]),
        latent_lengthscales=np.array([[1.5, 0.8], [3.0, 2.0]]),  # long: K^s nearly low rank
        action_lengthscales=np.array([[1.2, 2.0], [0.9, 1.4]]),
    )
    return data, latents, hyper


@pytest.mark.parametrize(("n_objects", "n_actions"), [(33, 4), (3, 40)])
def test_singular_factors_match_the_dense_path(n_objects: int, n_actions: int) -> None:
    data, latents, hyper = singular_problem(n_objects, n_actions, seed=n_objects)
    kron, vector, value_k = assert_kronecker_matches_dense(data, 2, latents, hyper)
    assert kron.value(vector) == pytest.approx(value_k, rel=1e-12)
    model_k = condition_kronecker(data, latents, hyper)
    model_d = condition(data, latents, hyper, structure="dense")
    beta_scale = np.max(np.abs(model_d.posterior.beta))
    assert np.max(np.abs(model_k.posterior.beta - model_d.posterior.beta)) <= TOLERANCE * beta_scale
