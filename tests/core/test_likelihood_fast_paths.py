"""The fast evaluation paths of the dense likelihood agree with the textbook formulas.

:class:`core.gp.likelihood.ManifoldLikelihood` forms one triangle of W = K⁻¹ - ββᵀ (the inverse
from the Cholesky factor by recursive GEMMs, :func:`core.gp.linalg.inverse_from_cholesky`) and
contracts it blockwise; :mod:`bench.direct_likelihood` builds every ∂K/∂θ densely and uses
:func:`numpy.linalg.inv`. Both are exact, so they agree to round-off.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import scipy.linalg

import core.gp.linalg
from bench.direct_likelihood import direct_value_and_gradient
from core.errors import InvalidInputError, NotPositiveDefiniteError
from core.gp.likelihood import LOWER_BLOCK_ROWS, ManifoldLikelihood, feature_data
from core.gp.linalg import inverse_from_cholesky, upper_triangular_inverse, weighted_gram_difference
from core.gp.parameters import ParameterLayout, initial_hyperparameters
from core.types import Hyperparameters, TrainingData

#: Relative agreement of two exact evaluations (values are O(10²), gradients O(10²)).
TOLERANCE = 1e-9


def _problem(
    n_objects: int, counts: list[int], dx: int, dy: int, ds: int, seed: int
) -> tuple[TrainingData, np.ndarray]:
    """Random touches (objects interleaved, uneven counts) and a random packed vector."""
    rng = np.random.default_rng(seed)
    index = rng.permutation(np.repeat(np.arange(n_objects), counts))
    n = index.size
    truth = rng.standard_normal((n_objects, ds))
    actions = rng.standard_normal((n, dx))
    weights = rng.standard_normal((ds + dx, dy))
    observations = np.sin(np.hstack([truth[index], actions]) @ weights)
    observations += 0.1 * rng.standard_normal((n, dy))
    data = TrainingData(tuple(f"o{i}" for i in range(n_objects)), index, actions, observations)
    layout = ParameterLayout.for_data(data, ds)
    vector = layout.pack(
        rng.standard_normal((n_objects, ds)),
        initial_hyperparameters(data, ds, latent_lengthscale=1.5),
    )
    return data, vector + 0.3 * rng.standard_normal(layout.size)


def _relative(value: np.ndarray, reference: np.ndarray) -> float:
    return float(np.max(np.abs(value - reference)) / np.max(np.abs(reference)))


@pytest.mark.parametrize(
    ("n_objects", "counts", "dx", "dy", "ds"),
    [
        (3, [4, 7, 5], 2, 2, 2),  # below the recursion block: LAPACK dtrtri
        (4, [40, 25, 50, 35], 3, 2, 2),  # N = 150: two levels of the recursive inverse
        (5, [30, 2, 20, 10, 21], 1, 1, 1),  # an object with two touches, N = 83
    ],
)
def test_value_and_gradient_match_the_direct_formula(
    n_objects: int,
    counts: list[int],
    dx: int,
    dy: int,
    ds: int,
) -> None:
    data, vector = _problem(n_objects, counts, dx, dy, ds, seed=sum(counts))
    likelihood = ManifoldLikelihood(data, ds)
    latents, hyper = likelihood.layout.unpack(vector)
    value_ref, grad_ref = direct_value_and_gradient(data, latents, hyper)
    value, grad = likelihood.value_and_gradient(vector)
    assert value == pytest.approx(value_ref, rel=TOLERANCE)
    assert _relative(grad, grad_ref) <= TOLERANCE
    assert likelihood.value(vector) == pytest.approx(value_ref, rel=TOLERANCE)


def test_noise_free_gram_matches_the_product_kernel() -> None:
    data, vector = _problem(3, [5, 6, 4], 2, 2, 2, seed=3)
    likelihood = ManifoldLikelihood(data, 2)
    latents, hyper = likelihood.layout.unpack(vector)
    order = np.argsort(data.object_index, kind="stable")
    obj = data.object_index[order]
    actions = data.actions[order]
    gram = likelihood.noise_free_gram(vector)
    for a in range(2):
        sq_s = np.sum(
            ((latents[obj][:, None] - latents[obj][None]) / hyper.latent_lengthscales[a]) ** 2,
            axis=2,
        )
        sq_x = np.sum(
            ((actions[:, None] - actions[None]) / hyper.action_lengthscales[a]) ** 2, axis=2
        )
        expected = hyper.signal_variance[a] * np.exp(-0.5 * sq_s) * np.exp(-0.5 * sq_x)
        np.testing.assert_allclose(gram[a], expected, rtol=1e-13, atol=1e-15)


def test_far_apart_objects_give_zeros_not_subnormal_numbers() -> None:
    """Objects many latent length-scales apart: their kernel entries (down to 10⁻³²⁴, subnormal
    numbers the processor computes with slowly) become exact zeros below 10⁻⁵⁰ σ_f², and the
    value and gradient still agree with the direct formula, which keeps every entry."""
    data, vector = _problem(4, [30, 25, 35, 20], 1, 2, 1, seed=11)
    layout = ParameterLayout.for_data(data, 1)
    _, hyper = layout.unpack(vector)
    spread = np.array([[0.0], [20.0], [40.0], [60.0]])
    short = Hyperparameters(
        hyper.signal_variance,
        hyper.noise_variance,
        np.full_like(hyper.latent_lengthscales, 1.6),
        hyper.action_lengthscales,
    )
    vector = layout.pack(spread, short)
    likelihood = ManifoldLikelihood(data, 1)
    gram = likelihood.noise_free_gram(vector)
    tiny = np.finfo(np.float64).tiny
    floor = hyper.signal_variance[:, None, None] * 10.0**-50
    assert np.any(gram == 0.0)  # the far blocks (exp(-20²/(2·1.6²)) ≈ 10⁻⁶⁸ and below)
    assert not np.any((gram != 0.0) & (np.abs(gram) < floor))
    assert not np.any((gram != 0.0) & (np.abs(gram) < tiny))
    value_ref, grad_ref = direct_value_and_gradient(data, spread, short)
    value, grad = likelihood.value_and_gradient(vector)
    assert value == pytest.approx(value_ref, rel=TOLERANCE)
    assert _relative(grad, grad_ref) <= TOLERANCE


def _spd(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    points = rng.standard_normal((n, 3))
    sq = np.sum((points[:, None] - points[None]) ** 2, axis=2)
    return np.exp(-0.5 * sq) + 1e-2 * np.eye(n)


@pytest.mark.parametrize("n", [1, 7, 64, 65, 150, 300, 600])  # 600: the dpotri branch
def test_inverse_from_cholesky_matches_numpy(n: int) -> None:
    matrix = _spd(n, seed=n)
    upper = scipy.linalg.cholesky(matrix, lower=False)
    result = inverse_from_cholesky(np.asfortranarray(upper))
    expected = np.linalg.inv(matrix)
    assert np.all(np.tril(result, -1) == 0.0)
    # The inverse's error is ~cond(K)·eps: cond ≈ 1e3-1e4 here.
    assert _relative(np.triu(result), np.triu(expected)) < 1e-11


def test_inverse_in_the_factors_memory_matches_the_copy() -> None:
    matrix = _spd(600, seed=3)  # above RECURSIVE_INVERSE_MAX: the dpotri branch
    upper = np.asfortranarray(scipy.linalg.cholesky(matrix, lower=False))
    copied = inverse_from_cholesky(upper)
    in_place = inverse_from_cholesky(upper.copy(order="F"), overwrite=True)
    np.testing.assert_array_equal(in_place, copied)
    assert _relative(np.triu(in_place), np.triu(np.linalg.inv(matrix))) < 1e-11


def test_recursive_and_lapack_inverse_branches_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    matrix = _spd(90, seed=1)
    upper = np.asfortranarray(scipy.linalg.cholesky(matrix, lower=False))
    recursive = inverse_from_cholesky(upper)
    monkeypatch.setattr(core.gp.linalg, "RECURSIVE_INVERSE_MAX", 10)
    lapack = inverse_from_cholesky(upper)
    monkeypatch.setattr(core.gp.linalg, "RECURSIVE_INVERSE_MAX", 1024)
    monkeypatch.setattr(core.gp.linalg, "TRIANGULAR_BLOCK", 4)  # five levels of halving
    deep = inverse_from_cholesky(upper)
    assert _relative(recursive, lapack) < 1e-12
    assert _relative(deep, lapack) < 1e-12
    assert np.all(np.tril(lapack, -1) == 0.0)


def test_upper_triangular_inverse_is_exact_on_a_triangle() -> None:
    rng = np.random.default_rng(2)
    upper = np.triu(rng.standard_normal((100, 100))) + 10.0 * np.eye(100)
    inverse = upper_triangular_inverse(upper)
    np.testing.assert_allclose(inverse @ upper, np.eye(100), atol=1e-13)
    assert np.all(np.tril(inverse, -1) == 0.0)


def test_a_singular_triangle_is_reported() -> None:
    upper = np.triu(np.ones((5, 5)))
    upper[2, 2] = 0.0
    with pytest.raises(NotPositiveDefiniteError, match="singular"):
        upper_triangular_inverse(upper)


@pytest.mark.parametrize("n", [5, 80])  # plain products below 32, dsyrk updates above
def test_weighted_gram_difference_handles_signs_and_zeros(n: int) -> None:
    rng = np.random.default_rng(n)
    left, right = rng.standard_normal((n, n)), rng.standard_normal((n, 7))
    left_weights = rng.uniform(0.1, 2.0, n)
    left_weights[:3] = [-1e-14, 0.0, -0.5]  # round-off negatives, zeros, real negatives
    right_weights = rng.uniform(0.1, 2.0, 7)
    right_weights[0] = -3e-15
    expected = (left * left_weights) @ left.T - (right * right_weights) @ right.T
    result = weighted_gram_difference(left, left_weights, right, right_weights)
    assert np.all(np.tril(result, -1) == 0.0)
    np.testing.assert_allclose(np.triu(result), np.triu(expected), rtol=1e-12, atol=1e-12)
    zeros = weighted_gram_difference(left, np.zeros(n), right, np.zeros(7))
    assert zeros.shape == (n, n)
    assert not np.any(zeros)


@pytest.mark.parametrize("threads", [2, 3])
def test_features_on_threads_give_the_one_thread_numbers_bit_for_bit(threads: int) -> None:
    # N = 600 > 512: the inverse is LAPACK's dpotri, the path of the real-sized fits.
    data, vector = _problem(6, [120, 80, 100, 110, 90, 100], 2, 5, 3, seed=3)
    serial = ManifoldLikelihood(data, 3)
    threaded = ManifoldLikelihood(data, 3, threads=threads)
    value, grad = serial.value_and_gradient(vector)
    value_t, grad_t = threaded.value_and_gradient(vector)
    assert value_t == value
    assert np.array_equal(grad_t, grad)
    assert threaded.value(vector) == serial.value(vector)


def test_a_feature_that_fails_on_a_thread_raises_its_error(monkeypatch: pytest.MonkeyPatch) -> None:
    data, vector = _problem(3, [4, 7, 5], 2, 3, 2, seed=4)
    likelihood = ManifoldLikelihood(data, 2, threads=2)
    factor = ManifoldLikelihood._factor

    def failing(self: ManifoldLikelihood, gram: np.ndarray, noise: float, feature: int) -> object:
        if feature == 1:
            raise NotPositiveDefiniteError(f"Gram matrix of feature {feature}")
        return factor(self, gram, noise, feature)

    both = ManifoldLikelihood._inverse

    def failing_both(
        self: ManifoldLikelihood, gram: np.ndarray, noise: float, feature: int
    ) -> object:
        if feature == 1:
            raise NotPositiveDefiniteError(f"Gram matrix of feature {feature}")
        return both(self, gram, noise, feature)

    monkeypatch.setattr(ManifoldLikelihood, "_factor", failing)
    monkeypatch.setattr(ManifoldLikelihood, "_inverse", failing_both)
    with pytest.raises(NotPositiveDefiniteError, match="feature 1"):
        likelihood.value_and_gradient(vector)
    with pytest.raises(NotPositiveDefiniteError, match="feature 1"):
        likelihood.value(vector)


@pytest.mark.parametrize("threads", [0, -1, 1.5, True, "2"])
def test_a_bad_thread_count_is_refused(threads: object) -> None:
    data, _ = _problem(3, [4, 7, 5], 2, 2, 2, seed=5)
    with pytest.raises(InvalidInputError, match="threads"):
        ManifoldLikelihood(data, 2, threads=threads)  # type: ignore[arg-type]


def test_one_feature_of_a_likelihood_is_the_one_feature_likelihood_bit_for_bit() -> None:
    """``for_feature`` shares the action caches but gives a one-feature likelihood's numbers."""
    data, _ = _problem(4, [9, 6, 11, 7], 3, 4, 2, seed=8)
    placements = np.arange(data.n_touches) // 3
    data = TrainingData(
        data.object_names, data.object_index, data.actions, data.observations, placements
    )
    shared = np.array([0.05, 0.1, 0.0, 0.2])
    whole = ManifoldLikelihood(data, 2, placement_variance=shared)
    rng = np.random.default_rng(3)
    for a in range(4):
        alone_data = feature_data(data, a)
        alone = ManifoldLikelihood(alone_data, 2, placement_variance=shared[a : a + 1])
        derived = whole.for_feature(a)
        vector = alone.layout.pack(
            rng.standard_normal((4, 2)), initial_hyperparameters(alone_data, 2, 1.5)
        )
        assert derived.value(vector) == alone.value(vector)
        value, gradient = derived.value_and_gradient(vector)
        expected_value, expected_gradient = alone.value_and_gradient(vector)
        assert value == expected_value
        np.testing.assert_array_equal(gradient, expected_gradient)
        assert derived.evaluations == 2
        assert whole.evaluations == 0
    with pytest.raises(InvalidInputError, match="feature"):
        whole.for_feature(4)


def test_the_lower_only_gram_is_the_kernel_on_and_below_the_diagonal() -> None:
    """Evaluations exponentiate only the lower triangle (in row blocks): it equals the full
    Gram matrix's there to the bit, and above the blocks it is not the kernel."""
    data, vector = _problem(4, [40, 25, 50, 35], 3, 2, 2, seed=21)  # N = 150: three blocks
    likelihood = ManifoldLikelihood(data, 2)
    latents, log_sf, _, log_ls, log_lx = likelihood.layout.split(vector)
    full = likelihood.gram_rows(latents, log_sf, log_ls, log_lx)
    lower = likelihood.gram_rows(latents, log_sf, log_ls, log_lx, lower_only=True)
    n = data.n_touches
    below = np.tril(np.ones((n, n), dtype=bool))
    assert np.array_equal(lower[:, below], full[:, below])
    assert np.all(np.isfinite(lower))
    far = np.triu(np.ones((n, n), dtype=bool), k=LOWER_BLOCK_ROWS)  # above every block
    assert np.any(far)
    assert not np.any(np.isclose(lower[:, far], full[:, far]))


_LOWER_GRAM = ManifoldLikelihood._feature_gram


def _whole_gram(
    self: ManifoldLikelihood, vector: np.ndarray, lower_only: bool = True
) -> Callable[[int], np.ndarray]:
    """The evaluations' Gram matrices made whole (what they were before the lower triangle)."""
    return _LOWER_GRAM(self, vector, lower_only=False)


@pytest.mark.parametrize("placements", [False, True])
def test_evaluations_on_the_lower_triangle_give_the_full_grams_numbers(
    monkeypatch: pytest.MonkeyPatch, placements: bool
) -> None:
    """Value and gradient (and the jitter ladder's, on duplicate touches) from the lower
    triangle alone are bit for bit those from the whole Gram matrix."""
    data, vector = _problem(4, [40, 25, 50, 35], 3, 2, 2, seed=22)
    # Duplicate touches with a vanishing noise: K singular, so the jitter ladder runs.
    actions = data.actions.copy()
    actions[1::2] = actions[::2][: actions[1::2].shape[0]]
    index = data.object_index.copy()
    index[1::2] = index[::2][: index[1::2].shape[0]]
    duplicated = TrainingData(data.object_names, index, actions, data.observations)
    layout = ParameterLayout.for_data(duplicated, 2)
    latents, hyper = layout.unpack(vector)
    tiny_noise = layout.pack(
        latents,
        Hyperparameters(
            hyper.signal_variance,
            np.full_like(hyper.noise_variance, 1e-30),
            hyper.latent_lengthscales,
            hyper.action_lengthscales,
        ),
    )
    for touches, at in ((data, vector), (duplicated, tiny_noise)):
        if placements:
            groups = np.arange(touches.n_touches) // 4
            touches = TrainingData(
                touches.object_names,
                touches.object_index,
                touches.actions,
                touches.observations,
                groups,
            )
        shared = np.array([0.05, 0.1]) if placements else None
        lower = ManifoldLikelihood(touches, 2, placement_variance=shared)
        value, gradient = lower.value_and_gradient(at)
        plain = lower.value(at)
        with monkeypatch.context() as patch:
            patch.setattr(ManifoldLikelihood, "_feature_gram", _whole_gram)
            full = ManifoldLikelihood(touches, 2, placement_variance=shared)
            expected_value, expected_gradient = full.value_and_gradient(at)
            assert full.value(at) == plain
        assert value == expected_value
        np.testing.assert_array_equal(gradient, expected_gradient)
        assert lower.max_jitter == full.max_jitter
        if at is tiny_noise:
            assert lower.max_jitter > 0.0
