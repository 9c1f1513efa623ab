"""Negative log-likelihood of the object manifold and its analytic gradient (docs/method.md M2)."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.gp.likelihood import (
    ManifoldLikelihood,
    negative_log_likelihood,
    negative_log_likelihood_and_gradient,
)
from core.gp.parameters import ParameterLayout, initial_hyperparameters, parameter_bounds
from core.gp.posterior import condition
from core.types import Hyperparameters, TrainingData


@dataclass(frozen=True)
class Case:
    """One problem shape for the property checks."""

    name: str
    n_objects: int
    touches_per_object: int
    action_dim: int
    observation_dim: int
    latent_dim: int
    shuffled: bool = False


# One list of cases drives every property check (scikit-learn style).
CASES = [
    Case("exp1-like", 4, 6, 1, 3, 1),
    Case("ds2-dx2-dy2", 3, 5, 2, 2, 2),
    Case("ds3>L-1", 3, 4, 2, 2, 3),
    Case("unsorted-touches", 4, 4, 3, 1, 2, shuffled=True),
    Case("uneven-objects", 2, 7, 1, 2, 1),
]
POINTS_PER_CASE = 3


def make_data(case: Case, rng: np.random.Generator) -> TrainingData:
    """Smooth responses of random object latents plus noise."""
    n = case.n_objects * case.touches_per_object
    index = np.repeat(np.arange(case.n_objects), case.touches_per_object)
    if case.name == "uneven-objects":
        index = np.array([0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1])
        n = index.size
    if case.shuffled:
        index = rng.permutation(index)
    truth = rng.standard_normal((case.n_objects, case.latent_dim))
    actions = rng.standard_normal((n, case.action_dim))
    weights = rng.standard_normal((case.latent_dim + case.action_dim, case.observation_dim))
    inputs = np.hstack([truth[index], actions])
    observations = np.sin(inputs @ weights) + 0.1 * rng.standard_normal((n, case.observation_dim))
    return TrainingData(
        object_names=tuple(f"o{i}" for i in range(case.n_objects)),
        object_index=index,
        actions=actions,
        observations=observations,
    )


def random_points(case: Case) -> list[tuple[TrainingData, np.ndarray]]:
    """POINTS_PER_CASE random packed vectors (latents and log-hyperparameters) per case."""
    rng = np.random.default_rng(zlib.crc32(case.name.encode()))
    data = make_data(case, rng)
    layout = ParameterLayout.for_data(data, case.latent_dim)
    base = layout.pack(
        rng.standard_normal((case.n_objects, case.latent_dim)),
        initial_hyperparameters(data, case.latent_dim, latent_lengthscale=1.5),
    )
    return [(data, base + 0.4 * rng.standard_normal(layout.size)) for _ in range(POINTS_PER_CASE)]


GROUPS = (
    "latents",
    "log_signal_variance",
    "log_noise_variance",
    "log_latent_lengthscales",
    "log_action_lengthscales",
)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_gradient_matches_central_differences(case: Case) -> None:
    for data, vector in random_points(case):
        likelihood = ManifoldLikelihood(data, case.latent_dim)
        _, grad = likelihood.value_and_gradient(vector)
        step = 1e-5
        numeric = np.empty_like(vector)
        for i in range(vector.size):
            e = np.zeros_like(vector)
            e[i] = step
            numeric[i] = (likelihood.value(vector + e) - likelihood.value(vector - e)) / (2 * step)
        layout = likelihood.layout
        for group in GROUPS:
            sl = getattr(layout, group)
            # Tolerance: central differences are accurate to ~1e-8 here (values are O(10)).
            np.testing.assert_allclose(
                grad[sl], numeric[sl], rtol=1e-5, atol=1e-6, err_msg=f"{case.name}: {group}"
            )


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_value_equals_condition_log_likelihood(case: Case) -> None:
    for data, vector in random_points(case):
        likelihood = ManifoldLikelihood(data, case.latent_dim)
        latents, hyper = likelihood.layout.unpack(vector)
        expected = -condition(data, latents, hyper).log_likelihood
        value, _ = likelihood.value_and_gradient(vector)
        assert likelihood.value(vector) == pytest.approx(expected, rel=1e-11, abs=1e-9)
        assert value == pytest.approx(expected, rel=1e-11, abs=1e-9)
        assert negative_log_likelihood(data, latents, hyper) == pytest.approx(
            expected, rel=1e-11, abs=1e-9
        )


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_gradient_dataclass_matches_packed_gradient(case: Case) -> None:
    data, vector = random_points(case)[0]
    likelihood = ManifoldLikelihood(data, case.latent_dim)
    latents, hyper = likelihood.layout.unpack(vector)
    value, grad = likelihood.value_and_gradient(vector)
    value2, gradient = negative_log_likelihood_and_gradient(data, latents, hyper)
    assert value2 == pytest.approx(value, rel=1e-12)
    for group in GROUPS:
        np.testing.assert_allclose(
            np.ravel(getattr(gradient, group)), grad[getattr(likelihood.layout, group)]
        )
    assert gradient.latents.shape == (case.n_objects, case.latent_dim)
    assert gradient.log_latent_lengthscales.shape == (case.observation_dim, case.latent_dim)
    assert gradient.log_action_lengthscales.shape == (case.observation_dim, case.action_dim)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_gradient_vanishes_along_shift_and_scale(case: Case) -> None:
    """The likelihood is invariant to shifting S and to scaling S and ℓ^s together — each
    latent dimension d on its own (s_·d and every feature's ℓ^s_d by one factor) — so the
    gradient is orthogonal to those directions (a check that could fail with a sign error).
    These ds exact scale symmetries are why fixing the latent spread during a fit cannot
    help L-BFGS-B: its steps already have no first-order component along them."""
    data, vector = random_points(case)[0]
    likelihood = ManifoldLikelihood(data, case.latent_dim)
    layout = likelihood.layout
    _, grad = likelihood.value_and_gradient(vector)
    latents = vector[layout.latents].reshape(case.n_objects, case.latent_dim)
    g_latents = grad[layout.latents].reshape(latents.shape)
    np.testing.assert_allclose(g_latents.sum(axis=0), 0.0, atol=1e-9)
    g_log_ls = grad[layout.log_latent_lengthscales].reshape(case.observation_dim, -1)
    scale_directions = np.sum(g_latents * latents, axis=0) + g_log_ls.sum(axis=0)  # (ds,)
    assert np.all(np.abs(scale_directions) < 1e-8 * max(1.0, float(np.abs(grad).max())))
    scaled = vector.copy()
    factors = 1.5 ** np.arange(1, case.latent_dim + 1)
    scaled[layout.latents] = (latents * factors).ravel()
    log_ls = vector[layout.log_latent_lengthscales].reshape(case.observation_dim, -1)
    scaled[layout.log_latent_lengthscales] = (log_ls + np.log(factors)).ravel()
    assert likelihood.value(scaled) == pytest.approx(likelihood.value(vector), abs=1e-9)


def test_pack_unpack_round_trip() -> None:
    rng = np.random.default_rng(3)
    data = make_data(CASES[1], rng)
    layout = ParameterLayout.for_data(data, 2)
    latents = rng.standard_normal((3, 2))
    hyper = Hyperparameters(
        signal_variance=np.array([1.5, 0.5]),
        noise_variance=np.array([0.1, 0.2]),
        latent_lengthscales=np.array([[1.0, 2.0], [3.0, 4.0]]),
        action_lengthscales=np.array([[0.5, 0.6], [0.7, 0.8]]),
    )
    vector = layout.pack(latents, hyper)
    assert vector.shape == (layout.size,)
    s, h = layout.unpack(vector)
    np.testing.assert_allclose(s, latents)
    np.testing.assert_allclose(h.latent_lengthscales, hyper.latent_lengthscales)
    np.testing.assert_allclose(h.action_lengthscales, hyper.action_lengthscales)
    assert len(layout.names()) == layout.size
    assert layout.names()[layout.log_noise_variance.start + 1] == "noise_variance[feature 1]"


def test_bounds_are_relative_to_the_data() -> None:
    rng = np.random.default_rng(4)
    data = make_data(CASES[0], rng)
    scaled = TrainingData(
        object_names=data.object_names,
        object_index=data.object_index,
        actions=10.0 * data.actions,
        observations=3.0 * data.observations,
    )
    layout = ParameterLayout.for_data(data, 1)
    lower, upper = parameter_bounds(data, layout, 5.0)
    lower2, upper2 = parameter_bounds(scaled, layout, 5.0)
    # σ² bounds move by log 9, action length-scale bounds by log 10, latent ones not at all.
    for group, shift in (
        ("log_signal_variance", np.log(9.0)),
        ("log_noise_variance", np.log(9.0)),
        ("log_action_lengthscales", np.log(10.0)),
        ("log_latent_lengthscales", 0.0),
    ):
        sl = getattr(layout, group)
        np.testing.assert_allclose(lower2[sl] - lower[sl], shift, atol=1e-12)
        np.testing.assert_allclose(upper2[sl] - upper[sl], shift, atol=1e-12)
    var_y = np.var(data.observations, axis=0)
    np.testing.assert_allclose(np.exp(upper[layout.log_noise_variance]), var_y)
    np.testing.assert_allclose(np.exp(lower[layout.log_noise_variance]), 1e-6 * var_y)
    np.testing.assert_allclose(np.exp(2 * lower[layout.log_latent_lengthscales]), 1e-4)


def test_duplicate_touches_need_jitter_and_it_is_reported() -> None:
    """Exact duplicate touches with a vanishing noise variance make K singular; the jitter
    ladder rescues it, the likelihood reports the jitter, and still equals condition()."""
    actions = np.array([[0.0], [0.0], [1.0], [0.5], [0.5], [2.0]])
    data = TrainingData(
        object_names=("a", "b"),
        object_index=np.array([0, 0, 0, 1, 1, 1]),
        actions=actions,
        observations=np.array([[0.1], [0.1], [0.5], [0.2], [0.2], [0.9]]),
    )
    latents = np.array([[0.0], [1.0]])
    hyper = Hyperparameters(
        signal_variance=np.array([1.0]),
        noise_variance=np.array([1e-30]),
        latent_lengthscales=np.array([[1.0]]),
        action_lengthscales=np.array([[1.0]]),
    )
    likelihood = ManifoldLikelihood(data, 1)
    vector = likelihood.layout.pack(latents, hyper)
    assert likelihood.max_jitter == 0.0
    value, grad = likelihood.value_and_gradient(vector)
    assert likelihood.max_jitter > 0.0
    model = condition(data, latents, hyper)
    assert likelihood.max_jitter == pytest.approx(float(model.posterior.jitter.max()))
    assert value == pytest.approx(-model.log_likelihood, rel=1e-9)
    assert likelihood.value(vector) == pytest.approx(value, rel=1e-12)
    assert np.all(np.isfinite(grad))


def test_clean_problem_needs_no_jitter() -> None:
    data, vector = random_points(CASES[0])[0]
    likelihood = ManifoldLikelihood(data, 1)
    likelihood.value_and_gradient(vector)
    assert likelihood.max_jitter == 0.0


@pytest.mark.parametrize("latent_dim", [0, -1, 1.5, True])
def test_bad_latent_dim_is_named(latent_dim: object) -> None:
    data, _ = random_points(CASES[0])[0]
    with pytest.raises(InvalidInputError, match="latent_dim"):
        ManifoldLikelihood(data, latent_dim)  # type: ignore[arg-type]


def test_wrong_latent_shape_is_named() -> None:
    data, vector = random_points(CASES[0])[0]
    _, hyper = ParameterLayout.for_data(data, 1).unpack(vector)
    with pytest.raises(InvalidInputError, match="latents"):
        negative_log_likelihood(data, np.zeros((3, 1)), hyper)


@pytest.mark.parametrize("case", CASES[:2], ids=lambda c: c.name)
def test_gram_in_expanded_form_is_exact_where_it_matters(case: Case) -> None:
    """The Gram matrix comes from log σ_f² - ½|z_i|² + z_i·z_j - ½|z_j|² (one GEMM), which
    loses ~ε|z|² where differences do not. Far from the origin (every action and latent shifted
    by 10³) and at short length-scales it still matches the kernel from the differences to
    10⁻¹², its diagonal is σ_f² exactly and no entry exceeds it, because actions and latents are
    centred first and the exponent is capped at log σ_f²."""
    data, vector = random_points(case)[0]
    far = TrainingData(
        actions=data.actions + 1e3,
        observations=data.observations,
        object_index=data.object_index,
        object_names=data.object_names,
    )
    likelihood = ManifoldLikelihood(far, case.latent_dim)
    latents, hyper = likelihood.layout.unpack(vector)
    short = Hyperparameters(
        hyper.signal_variance,
        hyper.noise_variance,
        0.05 * hyper.latent_lengthscales,
        0.05 * hyper.action_lengthscales,
    )
    vector = likelihood.layout.pack(latents + 1e3, short)
    gram = likelihood.noise_free_gram(vector)
    order = np.argsort(far.object_index, kind="stable")
    s, x = (latents + 1e3)[far.object_index[order]], far.actions[order]
    for a in range(case.observation_dim):
        exponent = -0.5 * (
            np.sum(((s[:, None] - s[None]) / short.latent_lengthscales[a]) ** 2, axis=2)
            + np.sum(((x[:, None] - x[None]) / short.action_lengthscales[a]) ** 2, axis=2)
        )
        expected = short.signal_variance[a] * np.exp(exponent)
        # (entries below 10⁻⁵⁰ σ_f² are exact zeros: LOG_KERNEL_FLOOR)
        floor = 1e-50 * short.signal_variance[a]
        np.testing.assert_allclose(gram[a], expected, rtol=1e-12, atol=floor)
        assert np.all(np.diag(gram[a]) == short.signal_variance[a])
        assert np.all(gram[a] <= short.signal_variance[a])
