"""The factor and the inverse by recursive halving: LAPACK's factor and NumPy's inverse to
round-off at every order (leaf, one split, several), the failing minor reported as ``dpotrf``
reports it, the triangles it must not touch left alone, and bad arrays refused."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.linalg.lapack

from core.errors import InvalidInputError
from core.gp.factor_inverse import LEAF_ORDER, factor_and_triangular_inverse, spd_inverse


def _spd(n: int, seed: int = 0, ridge: float = 1e-3) -> np.ndarray:
    """A Gram-like matrix: squared-exponential kernel on random points plus a small ridge, so
    its condition number is large (as a fit's K_a is), not a diagonally dominant toy."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(0.0, 4.0, size=(n, 2))
    squared = np.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=2)
    return np.asfortranarray(np.exp(-0.5 * squared) + ridge * np.eye(n))


@pytest.mark.parametrize("n", [1, 2, 17, LEAF_ORDER, LEAF_ORDER + 1, 250, 513, 800])
def test_factor_and_inverse_equal_lapack_and_numpy_to_round_off(n: int) -> None:
    matrix = _spd(n, seed=n)
    reference_factor = scipy.linalg.cholesky(matrix, lower=False)
    reference_inverse = np.linalg.inv(matrix)
    work = matrix.copy(order="F")
    info, inverse = spd_inverse(work)
    assert info == 0
    np.testing.assert_allclose(np.triu(work), reference_factor, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.tril(work, -1), np.tril(matrix, -1))  # left as it was
    assert not np.tril(inverse, -1).any()
    full = np.triu(inverse) + np.triu(inverse, 1).T
    scale = np.abs(reference_inverse).max()
    np.testing.assert_allclose(full, reference_inverse, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(full @ matrix, np.eye(n), rtol=0, atol=1e-8)


def test_the_triangular_inverse_inverts_the_factor() -> None:
    matrix = _spd(300, seed=3)
    work = matrix.copy(order="F")
    inverse = np.zeros((300, 300), order="F")
    assert factor_and_triangular_inverse(work, inverse) == 0
    upper = np.triu(work)
    np.testing.assert_allclose(np.triu(inverse) @ upper, np.eye(300), rtol=0, atol=1e-9)
    assert not np.tril(inverse, -1).any()


@pytest.mark.parametrize("bad_minor", [5, LEAF_ORDER + 40, 290])
def test_the_first_failing_minor_is_reported_as_dpotrf_reports_it(bad_minor: int) -> None:
    matrix = _spd(300, seed=1)
    matrix[bad_minor - 1, bad_minor - 1] = -1.0
    _, expected = scipy.linalg.lapack.dpotrf(matrix, lower=0)
    assert expected == bad_minor
    info, _ = spd_inverse(matrix.copy(order="F"))
    assert info == bad_minor


def test_an_empty_matrix_is_a_no_op() -> None:
    info, inverse = spd_inverse(np.zeros((0, 0), order="F"))
    assert info == 0
    assert inverse.shape == (0, 0)


@pytest.mark.parametrize(
    ("matrix", "inverse", "message"),
    [
        (np.ascontiguousarray(_spd(4) + np.triu(np.ones((4, 4)), 1)), None, "Fortran"),
        (_spd(4).astype(np.float32), None, "float64"),
        (_spd(4), np.zeros((3, 3), order="F"), "shape"),
        (_spd(4), np.zeros((4, 4), order="C") + np.triu(np.ones((4, 4)), 1), "Fortran"),
    ],
)
def test_bad_arrays_are_refused_before_blas_sees_them(
    matrix: np.ndarray, inverse: np.ndarray | None, message: str
) -> None:
    target = np.zeros((4, 4), order="F") if inverse is None else inverse
    with pytest.raises(InvalidInputError, match=message):
        factor_and_triangular_inverse(matrix, target)


def test_one_array_for_both_is_refused() -> None:
    matrix = _spd(4)
    with pytest.raises(InvalidInputError, match="share memory"):
        factor_and_triangular_inverse(matrix, matrix)
