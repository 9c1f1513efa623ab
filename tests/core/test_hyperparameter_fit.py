"""The separable hyperparameter fit (S fixed, one problem per feature) and the stall stop."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.optimize

from core.errors import InvalidInputError
from core.evaluation.designs import collect, shared_design
from core.evaluation.worlds import random_experiment2_world, sample_dataset
from core.gp.hyperparameter_fit import (
    feature_indices,
    iter_fit_separately,
    minimize_free,
)
from core.gp.initialisation import normalise_spread
from core.gp.likelihood import feature_data
from core.gp.manifold import FitOptions, fit_hyperparameters
from core.gp.parameters import ParameterLayout, initial_hyperparameters, parameter_bounds
from core.gp.posterior import make_likelihood
from core.types import TrainingData
from tests.core.badly_scaled import minimize_quadratic


def small_world_data(seed: int = 0, touches: int = 12) -> tuple[TrainingData, np.ndarray]:
    world = random_experiment2_world(np.random.default_rng(seed), n_objects=3, action_dim=2)
    data = sample_dataset(world, np.random.default_rng(seed + 1), touches)
    latents, _, _ = normalise_spread(world.latents)
    return data, latents


def run_separately(stream):  # type: ignore[no-untyped-def]
    events = []
    while True:
        try:
            events.append(next(stream))
        except StopIteration as stop:
            return events, stop.value


@pytest.mark.parametrize("structure", ["dense", "kronecker"])
def test_per_feature_likelihoods_sum_to_the_full_one(structure: str) -> None:
    world = random_experiment2_world(np.random.default_rng(3), n_objects=3, action_dim=2)
    design = shared_design(3, 6, world.action_mean, world.action_cov, np.random.default_rng(4))
    data = collect(world, design, np.random.default_rng(5))
    full = make_likelihood(data, 2, structure)
    layout = full.layout
    rng = np.random.default_rng(6)
    vector = layout.pack(rng.standard_normal((3, 2)), initial_hyperparameters(data, 2, 1.5))
    vector[layout.hyperparameters] += 0.2 * rng.standard_normal(layout.size - 6)
    value, grad = full.value_and_gradient(vector)
    total, latent_grad = 0.0, np.zeros(6)
    for a in range(data.observation_dim):
        part = make_likelihood(feature_data(data, a), 2, structure)
        idx = feature_indices(layout, a)
        v, g = part.value_and_gradient(vector[idx])
        total += v
        latent_grad += g[:6]
        # The feature's own hyperparameters get exactly the full gradient's entries.
        np.testing.assert_allclose(g[6:], grad[idx[6:]], rtol=1e-9, atol=1e-9)
    assert total == pytest.approx(value, rel=1e-10)
    np.testing.assert_allclose(latent_grad, grad[:6], rtol=1e-8, atol=1e-9)


def test_feature_indices_cover_each_hyperparameter_once() -> None:
    layout = ParameterLayout(n_objects=4, latent_dim=2, action_dim=3, observation_dim=5)
    seen = np.concatenate([feature_indices(layout, a)[8:] for a in range(5)])
    assert sorted(seen.tolist()) == list(range(layout.latents.stop, layout.size))
    names = layout.names()
    assert [names[i] for i in feature_indices(layout, 2)[8:]] == [
        "signal_variance[feature 2]",
        "noise_variance[feature 2]",
        "latent_lengthscale[feature 2, dim 0]",
        "latent_lengthscale[feature 2, dim 1]",
        "action_lengthscale[feature 2, dim 0]",
        "action_lengthscale[feature 2, dim 1]",
        "action_lengthscale[feature 2, dim 2]",
    ]


def test_separate_fit_is_at_least_as_good_as_the_joint_hyperparameter_fit() -> None:
    data, latents = small_world_data()
    full = make_likelihood(data, 2, "dense")
    layout = full.layout
    lower, upper = parameter_bounds(data, layout, 5.0)
    start = np.clip(layout.pack(latents, initial_hyperparameters(data, 2)), lower, upper)
    free = np.zeros(layout.size, dtype=bool)
    free[layout.hyperparameters] = True
    joint = minimize_free(full, start, free, lower, upper, 2000, 1e-12, 1e-8)
    features = [make_likelihood(feature_data(data, a), 2, "dense") for a in range(5)]
    events, result = run_separately(
        iter_fit_separately(features, layout, start, lower, upper, 2000, 1e-12, 1e-8, (1.0,))
    )
    assert [e.feature for e in events] == list(range(5))
    assert result.value <= float(joint.fun) + 1e-6
    # The reported value is the full likelihood at the returned vector; latents untouched.
    assert result.value == pytest.approx(full.value(result.vector), rel=1e-10)
    np.testing.assert_array_equal(result.vector[layout.latents], start[layout.latents])
    # Progress values only go down.
    values = [full.value(start)] + [e.value for e in events]
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(values))


def test_features_fitted_on_threads_give_the_one_thread_result_and_progress() -> None:
    data, latents = small_world_data(seed=3)
    layout = make_likelihood(data, 2, "dense").layout
    lower, upper = parameter_bounds(data, layout, 5.0)
    start = np.clip(layout.pack(latents, initial_hyperparameters(data, 2)), lower, upper)
    outcomes = []
    for threads in (1, 3):
        features = [make_likelihood(feature_data(data, a), 2, "dense") for a in range(5)]
        outcomes.append(
            run_separately(
                iter_fit_separately(
                    features, layout, start, lower, upper, 500, 1e-12, 1e-8, (1.0,), threads=threads
                )
            )
        )
    (events_1, result_1), (events_3, result_3) = outcomes
    np.testing.assert_array_equal(result_3.vector, result_1.vector)
    assert (result_3.value, result_3.iterations) == (result_1.value, result_1.iterations)
    assert (result_3.converged, result_3.message) == (result_1.converged, result_1.message)
    assert events_3 == events_1  # the same progress, in feature order


def test_unit_length_scale_start_avoids_the_independent_objects_corner() -> None:
    # L=4 objects, a shared design of 100 actions, dx=6: from ℓ^s = 10 alone the first
    # quasi-Newton steps throw every latent length-scale onto its lower bound (K^s = I).
    world = random_experiment2_world(np.random.default_rng(0), n_objects=4)
    design = shared_design(4, 100, world.action_mean, world.action_cov, np.random.default_rng(1))
    data = collect(world, design, np.random.default_rng(1))
    lower_ls = np.sqrt(1e-4)
    only_long = fit_hyperparameters(
        data, world.latents, FitOptions(hyperparameter_latent_lengthscales=())
    )
    both = fit_hyperparameters(data, world.latents)
    assert np.min(only_long.hyperparameters.latent_lengthscales) <= lower_ls * 1.01
    assert np.min(both.hyperparameters.latent_lengthscales) > 10 * lower_ls
    assert both.log_likelihood > only_long.log_likelihood + 100.0


def test_stall_stop_ends_a_creeping_run_successfully() -> None:
    # A badly scaled quadratic: L-BFGS-B needs many iterations to its tolerance.
    full = minimize_quadratic()
    stalled = minimize_quadratic(stall_nats=1e3, stall_iterations=3)
    assert isinstance(stalled, scipy.optimize.OptimizeResult)
    assert stalled.success
    assert "improved by <" in stalled.message
    assert stalled.nit == 4 < full.nit
    relative = minimize_quadratic(stall_relative=1e-1)
    assert relative.success
    assert relative.nit < full.nit


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("stall_nats", -1.0, "stall_nats: must be a finite number ≥ 0"),
        ("stall_relative", float("nan"), "stall_relative: must be a finite number ≥ 0"),
        ("stall_iterations", 0, "stall_iterations: must be ≥ 1"),
        ("hyperparameter_latent_lengthscales", (1.0, -2.0), "hyperparameter_latent_lengthscales"),
        ("hyperparameter_latent_lengthscales", [1.0], "expected a tuple"),
    ],
)
def test_bad_stall_and_start_options_are_named(field: str, value: object, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        FitOptions(**{field: value})  # type: ignore[arg-type]


def test_fit_hyperparameters_runs_the_features_on_the_threads_it_is_given(monkeypatch) -> None:
    """``FitOptions.threads`` reaches the features' problems (it was silently one thread), and
    the model is the one thread's, bit for bit."""
    import core.gp.fit_run as fit_run

    world = random_experiment2_world(np.random.default_rng(0), n_objects=3)
    data = sample_dataset(world, np.random.default_rng(1), touches_per_object=20)
    one = fit_hyperparameters(data, world.latents, FitOptions(max_iterations=30))
    seen: list[int] = []
    real = fit_run.iter_fit_separately

    def spy(*args, threads=1, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(threads)
        return real(*args, threads=threads, **kwargs)

    monkeypatch.setattr(fit_run, "iter_fit_separately", spy)
    two = fit_hyperparameters(data, world.latents, FitOptions(max_iterations=30, threads=2))
    assert seen == [2]
    assert two.log_likelihood == one.log_likelihood
    for name in ("signal_variance", "noise_variance", "latent_lengthscales", "action_lengthscales"):
        np.testing.assert_array_equal(
            getattr(two.hyperparameters, name), getattr(one.hyperparameters, name)
        )
