"""A latent per placement: the packed likelihood against the pseudo-objects' own, its gradient
against finite differences, the per-object standardisation of u, the fit's options, and the
trial score reducing to the ordinary joint one when placements do not matter."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.optimize

from core.errors import InvalidInputError
from core.evaluation.worlds import Experiment1World
from core.gp.likelihood import ManifoldLikelihood
from core.gp.parameters import parameter_bounds
from core.gp.placement_effect import trial_log_likelihoods as joint_log_likelihoods
from core.gp.placement_latent import PlacementLatentLikelihood, placements_of
from core.gp.placement_latent_fit import PlacementLatentFit, fit_placement_latents
from core.gp.posterior import condition
from core.recognition.placement_latent import placement_latent_model, trial_log_likelihoods
from core.types import Hyperparameters, TrainingData
from tests.core.finite_differences import central_differences

WORLD = Experiment1World(noise_std=0.05)
LATENTS = np.array([[-1.3], [-0.4], [0.5], [1.2]])
HYPER = Hyperparameters(
    signal_variance=np.array([0.18, 0.2, 0.27]),
    noise_variance=np.full(3, 0.01),
    latent_lengthscales=np.array([[1.9], [3.0], [8.0]]),
    action_lengthscales=np.array([[0.84], [0.88], [0.92]]),
)


def _shifted(touches: int, run: int, shift_std: float, seed: int) -> tuple[TrainingData, dict]:
    """Experiment 1 touches in runs of ``run`` per placement; each placement shifts the action
    the object feels by its own δ_p (the recorded action is not shifted). Returns the data and
    δ of every (object, placement)."""
    rng = np.random.default_rng(seed)
    object_index, placement, actions, observations, shifts = [], [], [], [], {}
    for obj in range(4):
        x = rng.normal(size=(touches, 1))
        p = np.arange(touches) // run
        delta = rng.normal(0.0, shift_std, size=p.max() + 1)
        shifts.update({(obj, k): float(d) for k, d in enumerate(delta)})
        y = WORLD.observe(obj, x + delta[p][:, None], rng)
        object_index.append(np.full(touches, obj))
        placement.append(p)
        actions.append(x)
        observations.append(y)
    data = TrainingData(
        WORLD.object_names,
        np.concatenate(object_index),
        np.concatenate(actions),
        np.concatenate(observations),
        np.concatenate(placement),
    )
    return data, shifts


def test_the_packed_likelihood_is_the_pseudo_objects_plus_the_prior() -> None:
    data, _ = _shifted(9, 3, 0.3, 0)
    likelihood = PlacementLatentLikelihood(data, 1)
    layout = likelihood.layout
    assert layout.n_placements == 12
    rng = np.random.default_rng(1)
    offsets = rng.normal(size=12)
    hyper = dataclasses.replace(
        HYPER, latent_lengthscales=np.column_stack([HYPER.latent_lengthscales, [0.7, 1.1, 2.0]])
    )
    vector = layout.pack(LATENTS, offsets, hyper)
    placements = placements_of(data)
    owner = placements.placement_object
    u = np.empty(12)
    expected = 0.0
    for obj in range(4):
        v = offsets[owner == obj]
        u[owner == obj] = (v - v.mean()) / v.std()
        expected += 0.5 * np.log(v.std()) ** 2
    pseudo_latents = np.column_stack([LATENTS[owner], u])
    direct = ManifoldLikelihood(placements.data, 2)
    expected += direct.value(direct.layout.pack(pseudo_latents, hyper))
    assert likelihood.value(vector) == pytest.approx(expected, rel=1e-12)
    # Each placement's pseudo-object holds exactly its touches.
    for p, owner in enumerate(placements.placement_object):
        rows = placements.data.object_index == p
        assert np.all(data.object_index[rows] == owner)
        assert np.unique(data.placement_index[rows]).size == 1


def test_the_gradient_matches_finite_differences() -> None:
    data, _ = _shifted(8, 2, 0.3, 2)
    likelihood = PlacementLatentLikelihood(data, 1)
    rng = np.random.default_rng(3)
    hyper = dataclasses.replace(
        HYPER, latent_lengthscales=np.column_stack([HYPER.latent_lengthscales, [0.7, 1.1, 2.0]])
    )
    vector = likelihood.layout.pack(LATENTS, rng.normal(size=16), hyper)
    _, gradient = likelihood.value_and_gradient(vector)
    numeric = central_differences(likelihood.value, vector, step=1e-6)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-5)


def test_touches_without_placements_are_refused() -> None:
    data, _ = _shifted(6, 2, 0.3, 0)
    bare = dataclasses.replace(data, placement_index=None)
    with pytest.raises(InvalidInputError, match="placement"):
        PlacementLatentLikelihood(bare, 1)


def _fit(shift_std: float, seed: int, **options: object) -> tuple[TrainingData, PlacementLatentFit]:
    data, _ = _shifted(30, 3, shift_std, seed)
    fit = fit_placement_latents(data, LATENTS, HYPER, seed=seed, max_iterations=150, **options)
    return data, fit


def test_each_objects_offsets_have_zero_mean_and_unit_spread() -> None:
    """The mechanism that keeps u from shrinking with ℓ^u or standing for the object."""
    _, fit = _fit(0.4, 4)
    owner = fit.placements.placement_object
    for obj in range(4):
        u = fit.offsets[owner == obj]
        assert abs(u.mean()) < 1e-12
        assert np.sqrt(np.mean(u**2)) == pytest.approx(1.0, abs=1e-12)
    assert fit.pseudo_latents.shape == (40, 2)
    np.testing.assert_array_equal(fit.pseudo_latents[:, 0], fit.latents[owner, 0])


def _without_offsets(data: TrainingData) -> float:
    """-log p of the same touches fitted from the same start without u (150 iterations)."""
    likelihood = ManifoldLikelihood(data, 1)
    lower, upper = parameter_bounds(data, likelihood.layout, 10.0)
    start = np.clip(likelihood.layout.pack(LATENTS, HYPER), lower, upper)
    result = scipy.optimize.minimize(
        likelihood.value_and_gradient,
        start,
        jac=True,
        method="L-BFGS-B",
        bounds=list(zip(lower, upper, strict=True)),
        options={"maxiter": 150},
    )
    return float(result.fun)


def test_the_offsets_explain_a_placements_shift_not_only_noise() -> None:
    """Where every placement shifts the action the object feels, u gains far more over a fit
    without it (187 nats when written) than where placements do not matter (30 nats: what 40
    free u_p take from the noise alone)."""
    gains = {}
    for shift in (0.4, 0.0):
        data, fit = _fit(shift, 4)
        gains[shift] = _without_offsets(data) - fit.negative_log_posterior
    assert gains[0.4] > 100.0, gains
    assert 0.0 < gains[0.0] < 60.0, gains


def test_a_noise_floor_holds() -> None:
    floor = np.full(3, 0.008)
    _, floored = _fit(0.4, 4, noise_floor=floor)
    assert np.all(floored.hyperparameters.noise_variance >= floor * (1 - 1e-12))


def test_a_placement_variance_beside_u_is_in_the_score() -> None:
    """With σ_b² in the fit, the conditioned GP's noise is the within-placement noise plus σ_b²
    and a trial's touches share σ_b²."""
    data, fit = _fit(0.4, 4, placement_variance=np.full(3, 0.004))
    np.testing.assert_allclose(fit.placement_variance, 0.004)
    base = condition(data, LATENTS, HYPER, structure="dense")
    model = placement_latent_model(base, fit)
    np.testing.assert_allclose(
        model.conditioned.hyperparameters.noise_variance,
        fit.hyperparameters.noise_variance + 0.004,
    )
    np.testing.assert_allclose(model.shared_variance, 0.004)
    with pytest.raises(InvalidInputError, match="placement_variance"):
        fit_placement_latents(data, LATENTS, HYPER, placement_variance=HYPER.noise_variance)


def test_with_placements_that_do_not_matter_the_score_is_the_joint_one() -> None:
    """ℓ^u → ∞: every placement answers alike, the pseudo-objects' GP is the objects' GP, and
    the trial score is the ordinary joint likelihood (docs/calibration.md (C3))."""
    data, _ = _shifted(12, 3, 0.0, 5)
    placements = placements_of(data)
    offsets = np.random.default_rng(6).normal(size=placements.n_placements)
    wide = dataclasses.replace(
        HYPER, latent_lengthscales=np.column_stack([HYPER.latent_lengthscales, [1e7] * 3])
    )
    fit = PlacementLatentFit(
        placements=placements,
        latents=LATENTS,
        offsets=offsets,
        hyperparameters=wide,
        negative_log_posterior=0.0,
        iterations=0,
        message="",
    )
    base = condition(data, LATENTS, HYPER, structure="dense")
    model = placement_latent_model(base, fit)
    rng = np.random.default_rng(7)
    x = rng.normal(size=(4, 1))
    y = WORLD.observe(2, x, rng)
    expected = joint_log_likelihoods(base, x, y, np.zeros(3))
    np.testing.assert_allclose(trial_log_likelihoods(model, x, y), expected, rtol=1e-7)


def test_a_shared_variance_above_the_noise_is_refused() -> None:
    data, fit = _fit(0.4, 4)
    base = condition(data, LATENTS, HYPER, structure="dense")
    with pytest.raises(InvalidInputError, match="shared_variance"):
        placement_latent_model(base, fit, shared_variance=fit.hyperparameters.noise_variance)
