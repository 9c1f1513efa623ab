"""Tied kernels: the likelihood with one eigendecomposition for every feature, and fits with it
(core/gp/tied_likelihood.py, docs/fitting.md "Tied kernels")."""

from __future__ import annotations

import dataclasses
import zlib

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.gp.fit_options import FitOptions
from core.gp.fit_run import FitRun, WarmStart
from core.gp.likelihood import ManifoldLikelihood
from core.gp.manifold import fit_hyperparameters, fit_manifold, iter_fit, refit_warm
from core.gp.parameters import ParameterLayout, initial_hyperparameters, parameter_bounds
from core.gp.placement_effect import with_placement_effect
from core.gp.posterior import make_likelihood
from core.gp.tied_likelihood import TiedLikelihood
from core.types import ManifoldModel, TrainingData
from tests.core.finite_differences import central_differences
from tests.core.test_likelihood import CASES, Case, make_data


def tied_points(case: Case) -> list[tuple[TrainingData, np.ndarray]]:
    """Three random tied packed vectors per case."""
    rng = np.random.default_rng(zlib.crc32(case.name.encode()) + 1)
    data = make_data(case, rng)
    layout = ParameterLayout.for_data(data, case.latent_dim, tied=True)
    base = layout.pack(
        rng.standard_normal((case.n_objects, case.latent_dim)),
        initial_hyperparameters(data, case.latent_dim, latent_lengthscale=1.5),
    )
    return [(data, base + 0.4 * rng.standard_normal(layout.size)) for _ in range(3)]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_tied_value_and_gradient_equal_the_per_feature_likelihood_at_shared_lengthscales(
    case: Case,
) -> None:
    for data, vector in tied_points(case):
        tied = TiedLikelihood(data, case.latent_dim)
        direct = ManifoldLikelihood(data, case.latent_dim)
        latents, hyper = tied.layout.unpack(vector)
        per_feature = direct.layout.pack(latents, hyper)
        value, grad = tied.value_and_gradient(vector)
        expected_value, expected_grad = direct.value_and_gradient(per_feature)
        # Tolerance: an eigendecomposition against Cholesky factors, ~1e-14 relative measured.
        assert value == pytest.approx(expected_value, rel=1e-10)
        assert tied.value(vector) == pytest.approx(expected_value, rel=1e-10)
        s, sf, sn, ls, lx = tied.layout.split(grad)
        es, esf, esn, els, elx = direct.layout.split(expected_grad)
        scale = max(1.0, float(np.max(np.abs(expected_grad))))
        for got, want, name in (
            (s, es, "latents"),
            (sf, esf, "log σ_f²"),
            (sn, esn, "log σ_n²"),
            # A shared length-scale moves every feature's: its gradient is their sum.
            (ls[0], els.sum(axis=0), "log ℓ^s"),
            (lx[0], elx.sum(axis=0), "log ℓ^x"),
        ):
            np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-10 * scale, err_msg=name)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_tied_gradient_matches_central_differences(case: Case) -> None:
    for data, vector in tied_points(case)[:2]:
        tied = TiedLikelihood(data, case.latent_dim)
        _, grad = tied.value_and_gradient(vector)
        numeric = central_differences(tied.value, vector, step=1e-5)
        # Tolerance: central differences are accurate to ~1e-8 here (values are O(10)).
        np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-6, err_msg=case.name)


def test_tied_layout_shares_one_row_of_lengthscales() -> None:
    data = make_data(CASES[1], np.random.default_rng(0))  # dy = 2, ds = 2, dx = 2
    layout = ParameterLayout.for_data(data, 2, tied=True)
    per_feature = ParameterLayout.for_data(data, 2)
    assert layout.size == per_feature.size - (2 - 1) * (2 + 2)
    lower, upper = parameter_bounds(data, layout, 5.0)
    assert lower.shape == upper.shape == (layout.size,)
    hyper = initial_hyperparameters(data, 2)
    latents = np.random.default_rng(1).standard_normal((data.n_objects, 2))
    back_latents, back = layout.unpack(layout.pack(latents, hyper))
    np.testing.assert_array_equal(back_latents, latents)
    np.testing.assert_allclose(back.latent_lengthscales, hyper.latent_lengthscales, rtol=1e-15)
    np.testing.assert_allclose(back.action_lengthscales, hyper.action_lengthscales, rtol=1e-15)
    assert "latent_lengthscale[every feature, dim 1]" in layout.names()
    # A per-feature model packs to the geometric mean of its length-scales.
    uneven = dataclasses.replace(hyper, latent_lengthscales=np.array([[1.0, 2.0], [4.0, 8.0]]))
    _, mean = layout.unpack(layout.pack(latents, uneven))
    np.testing.assert_allclose(mean.latent_lengthscales, [[2.0, 4.0], [2.0, 4.0]], rtol=1e-12)


def world(seed: int = 0, n_objects: int = 5, touches: int = 12, dy: int = 4) -> TrainingData:
    """A 1-D manifold seen through dy features that share one smoothness (what tying assumes)."""
    rng = np.random.default_rng(seed)
    theta = np.linspace(-1.0, 1.0, n_objects)
    index = np.repeat(np.arange(n_objects), touches)
    x = rng.uniform(-2.0, 2.0, (index.size, 1))
    phases = rng.uniform(0.0, np.pi, dy)
    observations = np.sin(x + 1.5 * theta[index, None] + phases[None, :]) * rng.uniform(0.5, 3, dy)
    observations += 0.05 * rng.standard_normal(observations.shape)
    return TrainingData(
        object_names=tuple(f"o{i}" for i in range(n_objects)),
        object_index=index,
        actions=x,
        observations=observations,
    )


def assert_shared(lengthscales: np.ndarray) -> None:
    """Every feature's row of length-scales is the same (bit for bit)."""
    np.testing.assert_array_equal(
        lengthscales, np.broadcast_to(lengthscales[:1], lengthscales.shape)
    )


TIED = FitOptions(kernels="tied", restarts=1, screen_touches_per_object=6)


@pytest.fixture(scope="module")
def tied_fit() -> tuple[TrainingData, ManifoldModel]:
    data = world()
    return data, fit_manifold(data, 1, np.random.default_rng(3), TIED)


def test_tied_fit_recovers_the_manifold_with_equal_lengthscales(
    tied_fit: tuple[TrainingData, ManifoldModel],
) -> None:
    data, model = tied_fit
    h = model.hyperparameters
    assert h.latent_lengthscales.shape == (data.observation_dim, 1)
    assert_shared(h.latent_lengthscales)
    assert_shared(h.action_lengthscales)
    assert len(set(h.signal_variance.tolist())) == data.observation_dim  # still per feature
    theta = np.linspace(-1.0, 1.0, data.n_objects)
    assert abs(np.corrcoef(theta, model.latents[:, 0])[0, 1]) > 0.98
    assert model.diagnostics is not None
    assert model.diagnostics.kernels == "tied"
    # The model's log-likelihood is the tied likelihood's optimum, and the per-feature model
    # (more freedom) reaches at least as high on the same data.
    per_feature = fit_manifold(
        data, 1, np.random.default_rng(3), dataclasses.replace(TIED, kernels="per_feature")
    )
    assert per_feature.diagnostics is not None
    assert per_feature.diagnostics.kernels == "per_feature"
    assert per_feature.log_likelihood >= model.log_likelihood - 1.0


def test_every_stage_of_a_tied_fit_uses_the_tied_likelihood() -> None:
    data = world(seed=1, touches=10, dy=3)
    run = FitRun(data, 1, np.random.default_rng(0), TIED)
    assert isinstance(run.full.likelihood, TiedLikelihood)
    assert run.screen is not None
    assert run.screen is not run.full
    assert isinstance(run.screen.likelihood, TiedLikelihood)
    assert run.layout.tied


def test_warm_refit_and_noise_model_refit_stay_tied(
    tied_fit: tuple[TrainingData, ManifoldModel],
) -> None:
    data, model = tied_fit
    keep = np.arange(data.n_touches) % 4 != 0
    train = TrainingData(
        data.object_names, data.object_index[keep], data.actions[keep], data.observations[keep]
    )
    refit = refit_warm(train, model, TIED)
    assert refit.diagnostics is not None
    assert refit.diagnostics.kernels == "tied"
    assert_shared(refit.hyperparameters.latent_lengthscales)
    events = list(iter_fit(data, 1, np.random.default_rng(0), TIED, noise_model="correlated"))
    final = events[-1].model
    assert final is not None
    assert final.diagnostics is not None
    assert final.diagnostics.kernels == "tied"
    h = final.hyperparameters
    assert_shared(h.action_lengthscales)


def test_fixed_latents_tied_fit_shares_lengthscales(
    tied_fit: tuple[TrainingData, ManifoldModel],
) -> None:
    data, model = tied_fit
    fixed = fit_hyperparameters(data, model.latents, TIED)
    h = fixed.hyperparameters
    assert_shared(h.latent_lengthscales)
    assert fixed.diagnostics is not None
    assert fixed.diagnostics.kernels == "tied"
    assert fixed.log_likelihood == pytest.approx(model.log_likelihood, abs=1.0)


@pytest.mark.parametrize("structure", ["kronecker", "sparse"])
def test_tied_kernels_refuse_kronecker_and_sparse(structure: str) -> None:
    with pytest.raises(InvalidInputError, match="tied.*" + structure):
        FitOptions(kernels="tied", structure=structure)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="tied"):
        make_likelihood(world(), 1, structure, kernels="tied")  # type: ignore[arg-type]


def test_unknown_kernels_are_named() -> None:
    with pytest.raises(InvalidInputError, match="kernels: expected one of per_feature, tied"):
        FitOptions(kernels="shared")  # type: ignore[arg-type]


def test_tied_auto_structure_is_dense_even_on_a_shared_design() -> None:
    data = world(touches=6)
    shared = TrainingData(
        data.object_names,
        data.object_index,
        np.tile(data.actions[:6], (data.n_objects, 1)),
        data.observations,
    )
    run = FitRun(shared, 1, np.random.default_rng(0), dataclasses.replace(TIED, structure="auto"))
    assert run.structure == "dense"
    assert isinstance(run.full.likelihood, TiedLikelihood)


def test_placement_effect_is_refused_in_a_tied_likelihood_and_kept_for_scoring(
    tied_fit: tuple[TrainingData, ManifoldModel],
) -> None:
    data, model = tied_fit
    placements = np.arange(data.n_touches) // 3
    placed = dataclasses.replace(data, placement_index=placements)
    warm = WarmStart(model.latents, model.hyperparameters, np.full(data.observation_dim, 1e-3))
    with pytest.raises(InvalidInputError, match="tied kernels have no placement effect"):
        FitRun(placed, 1, np.random.default_rng(0), TIED, warm_start=warm)
    with pytest.raises(InvalidInputError, match="tied kernels have no placement effect"):
        make_likelihood(
            placed, 1, "dense", placement_variance=np.zeros(data.observation_dim), kernels="tied"
        )
    placed_model = fit_manifold(placed, 1, np.random.default_rng(3), TIED)
    scored, estimate = with_placement_effect(placed_model, TIED)
    assert estimate is not None
    assert not scored.placement_in_fit  # the tied fit is kept; σ_b² only scores trials
    assert scored.log_likelihood == placed_model.log_likelihood
