"""The inverse and log determinant by recursive halving, in place: NumPy's inverse and log
determinant to round-off at every order (leaf, one split, several), U⁻¹ the inverse of LAPACK's
factor, the failing minor reported as ``dpotrf`` reports it, the triangle the caller reads zeroed
and the one it must not touch left alone, and bad arrays refused."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.linalg.lapack

from core.errors import InvalidInputError
from core.gp.factor_inverse import LEAF_ORDER, spd_inverse, triangular_inverse_of_factor


def _spd(n: int, seed: int = 0, ridge: float = 1e-3) -> np.ndarray:
    """A Gram-like matrix: squared-exponential kernel on random points plus a small ridge, so
    its condition number is large (as a fit's K_a is), not a diagonally dominant toy."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(0.0, 4.0, size=(n, 2))
    squared = np.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=2)
    return np.asfortranarray(np.exp(-0.5 * squared) + ridge * np.eye(n))


@pytest.mark.parametrize("n", [1, 2, 17, LEAF_ORDER, LEAF_ORDER + 1, 250, 513, 800])
def test_inverse_and_log_det_equal_numpy_to_round_off(n: int) -> None:
    matrix = _spd(n, seed=n)
    reference_inverse = np.linalg.inv(matrix)
    sign, reference_log_det = np.linalg.slogdet(matrix)
    assert sign == 1.0
    work = matrix.copy(order="F")
    info, log_det = spd_inverse(work)
    assert info == 0
    assert not np.tril(work, -1).any()  # the caller reads the transpose's lower triangle
    full = np.triu(work) + np.triu(work, 1).T
    scale = np.abs(reference_inverse).max()
    np.testing.assert_allclose(full, reference_inverse, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(full @ matrix, np.eye(n), rtol=0, atol=1e-8)
    assert log_det == pytest.approx(reference_log_det, rel=1e-12, abs=1e-10)


def test_the_triangular_inverse_inverts_lapacks_factor() -> None:
    matrix = _spd(300, seed=3)
    upper = scipy.linalg.cholesky(matrix, lower=False)
    work = matrix.copy(order="F")
    info, diagonal = triangular_inverse_of_factor(work)
    assert info == 0
    np.testing.assert_allclose(diagonal, np.diag(upper), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.triu(work) @ upper, np.eye(300), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.tril(work, -1), np.tril(matrix, -1))  # left as it was


@pytest.mark.parametrize("bad_minor", [5, LEAF_ORDER + 40, 290])
def test_the_first_failing_minor_is_reported_as_dpotrf_reports_it(bad_minor: int) -> None:
    matrix = _spd(300, seed=1)
    matrix[bad_minor - 1, bad_minor - 1] = -1.0
    _, expected = scipy.linalg.lapack.dpotrf(matrix, lower=0)
    assert expected == bad_minor
    info, log_det = spd_inverse(matrix.copy(order="F"))
    assert info == bad_minor
    assert np.isnan(log_det)


def test_an_empty_matrix_is_a_no_op() -> None:
    assert spd_inverse(np.zeros((0, 0), order="F")) == (0, 0.0)


@pytest.mark.parametrize(
    ("matrix", "message"),
    [
        (np.ascontiguousarray(_spd(4) + np.triu(np.ones((4, 4)), 1)), "Fortran"),
        (_spd(4).astype(np.float32), "float64"),
        (np.asfortranarray(np.ones((4, 3))), "square"),
    ],
)
def test_bad_arrays_are_refused_before_lapack_sees_them(matrix: np.ndarray, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        spd_inverse(matrix)
