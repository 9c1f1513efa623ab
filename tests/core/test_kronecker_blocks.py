"""The few-objects Kronecker evaluation (L Cholesky blocks, :mod:`core.gp.kronecker_blocks`)
matches the dense path and the eigendecomposition path, and falls back where it must."""

from __future__ import annotations

import numpy as np
import pytest

import core.gp.kronecker
from core.gp.kronecker import KroneckerLikelihood
from core.gp.kronecker_blocks import (
    BLOCK_MAX_OBJECTS,
    BLOCK_MIN_ACTIONS,
    NOISE_FRACTION_FLOOR,
    block_sums,
    use_blocks,
)
from core.gp.likelihood import ManifoldLikelihood
from core.gp.manifold import FitOptions, fit_hyperparameters
from core.types import Hyperparameters, TrainingData
from tests.core.finite_differences import central_differences
from tests.core.test_kronecker import CASES, TOLERANCE, Case, make_problem, relative
from tests.core.test_kronecker_fast_paths import singular_problem

#: A case the default rule evaluates through the blocks.
FEW_OBJECTS = Case("few-objects", 3, 60, 3, 2, 2)


def both_paths(
    data: TrainingData, latent_dim: int, vector: np.ndarray
) -> tuple[tuple[float, np.ndarray], tuple[float, np.ndarray], KroneckerLikelihood]:
    """Value and gradient through the blocks and through the eigendecompositions."""
    blocks = KroneckerLikelihood(data, latent_dim)
    blocks.blocks = True
    eigen = KroneckerLikelihood(data, latent_dim)
    eigen.blocks = False
    return blocks.value_and_gradient(vector), eigen.value_and_gradient(vector), blocks


@pytest.mark.parametrize("case", [*CASES, FEW_OBJECTS], ids=lambda c: c.name)
def test_blocks_match_the_dense_and_the_eigendecomposition_paths(case: Case) -> None:
    data, latents, hyper = make_problem(case, seed=3)
    dense = ManifoldLikelihood(data, case.latent_dim)
    vector = dense.layout.pack(latents, hyper)
    (value_b, grad_b), (value_e, grad_e), blocks = both_paths(data, case.latent_dim, vector)
    value_d, grad_d = dense.value_and_gradient(vector)
    assert abs(value_b - value_d) <= TOLERANCE * abs(value_d)
    assert relative(grad_b, grad_d) <= TOLERANCE
    assert abs(value_b - value_e) <= 1e-12 * abs(value_e)
    assert relative(grad_b, grad_e) <= 1e-10
    assert blocks.value(vector) == pytest.approx(value_b, rel=1e-12)


def test_the_default_rule_uses_blocks_for_few_objects_on_many_actions() -> None:
    assert use_blocks(BLOCK_MAX_OBJECTS, BLOCK_MIN_ACTIONS)
    assert not use_blocks(BLOCK_MAX_OBJECTS + 1, 100)
    assert not use_blocks(2, BLOCK_MIN_ACTIONS - 1)
    data, _, _ = make_problem(FEW_OBJECTS, seed=4)
    assert KroneckerLikelihood(data, 2).blocks
    small, _, _ = make_problem(CASES[0], seed=4)  # 4 objects, 10 actions
    assert not KroneckerLikelihood(small, 2).blocks


def test_block_gradient_matches_finite_differences() -> None:
    data, latents, hyper = make_problem(FEW_OBJECTS, seed=5)
    likelihood = KroneckerLikelihood(data, 2)
    assert likelihood.blocks
    vector = likelihood.layout.pack(latents, hyper)
    _, grad = likelihood.value_and_gradient(vector)
    numeric = central_differences(likelihood.value, vector)
    assert relative(grad, numeric) < 1e-6


def test_blocks_of_singular_latent_and_action_grams_match_the_dense_path() -> None:
    """Coincident objects (λ_j at round-off around zero: B_j = σ_n² I) and a repeated design
    action (K^x singular)."""
    data, latents, hyper = singular_problem(n_objects=4, n_actions=50, seed=6)
    dense = ManifoldLikelihood(data, 2)
    vector = dense.layout.pack(latents, hyper)
    (value_b, grad_b), _, blocks = both_paths(data, 2, vector)
    assert blocks.blocks
    value_d, grad_d = dense.value_and_gradient(vector)
    assert abs(value_b - value_d) <= TOLERANCE * abs(value_d)
    assert np.max(np.abs(grad_b - grad_d)) <= TOLERANCE * np.max(np.abs(grad_d))


def test_a_noise_variance_below_the_floor_falls_back_to_the_eigendecompositions() -> None:
    data, latents, hyper = make_problem(FEW_OBJECTS, seed=7)
    noise = hyper.noise_variance.copy()
    noise[1] = 0.1 * NOISE_FRACTION_FLOOR * hyper.signal_variance[1]
    hyper = Hyperparameters(
        hyper.signal_variance, noise, hyper.latent_lengthscales, hyper.action_lengthscales
    )
    likelihood = KroneckerLikelihood(data, 2)
    assert likelihood.blocks
    vector = likelihood.layout.pack(latents, hyper)
    latent_gram, action_gram, _ = likelihood._grams(vector)
    grid_y = likelihood._grid_y
    assert block_sums(latent_gram, action_gram, grid_y, hyper.signal_variance, noise) is None
    (value_b, grad_b), (value_e, grad_e), _ = both_paths(data, 2, vector)
    assert value_b == value_e
    np.testing.assert_array_equal(grad_b, grad_e)


def test_a_hyperparameter_fit_reaches_the_same_optimum_through_the_blocks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    data, latents, _ = make_problem(FEW_OBJECTS, seed=8, shuffle=False)
    options = FitOptions(hyperparameter_latent_lengthscales=())
    with_blocks = fit_hyperparameters(data, latents, options)
    monkeypatch.setattr(core.gp.kronecker, "use_blocks", lambda n_objects, n_actions: False)
    without = fit_hyperparameters(data, latents, options)
    assert with_blocks.posterior.structure == without.posterior.structure == "kronecker"
    assert with_blocks.log_likelihood == pytest.approx(without.log_likelihood, abs=1e-3)
