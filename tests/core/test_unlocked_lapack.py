"""LAPACK through SciPy's Cython pointers: the f2py wrappers' results bit for bit, errors
before any out-of-bounds call, and the GIL released during the call."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import scipy.linalg.lapack
from threadpoolctl import threadpool_limits

from core.errors import InvalidInputError
from core.gp.unlocked_lapack import lauum_upper, potrf_upper, potri_upper, trtri_upper


def _spd(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    return np.asfortranarray(a @ a.T + n * np.eye(n))


@pytest.mark.parametrize("n", [1, 7, 130, 600])
def test_the_four_routines_equal_the_f2py_wrappers_bit_for_bit(n: int) -> None:
    matrix = _spd(n, seed=n)
    reference, info = scipy.linalg.lapack.dpotrf(matrix, lower=0, clean=1)
    assert info == 0
    factor = matrix.copy(order="F")
    assert potrf_upper(factor) == 0
    np.testing.assert_array_equal(factor, reference)  # the strictly lower triangle zeroed too

    expected_inverse, _ = scipy.linalg.lapack.dpotri(reference, lower=0)
    inverse = factor.copy(order="F")
    assert potri_upper(inverse) == 0
    np.testing.assert_array_equal(np.triu(inverse), np.triu(expected_inverse))
    np.testing.assert_allclose(
        np.triu(inverse) + np.triu(inverse, 1).T, np.linalg.inv(matrix), rtol=1e-8, atol=1e-12
    )

    expected_triangular, _ = scipy.linalg.lapack.dtrtri(reference, lower=0)
    triangular = factor.copy(order="F")
    assert trtri_upper(triangular) == 0
    np.testing.assert_array_equal(triangular, expected_triangular)

    expected_product, _ = scipy.linalg.lapack.dlauum(expected_triangular, lower=0)
    product = triangular.copy(order="F")
    assert lauum_upper(product) == 0
    np.testing.assert_array_equal(np.triu(product), np.triu(expected_product))


def test_potrf_reports_the_failing_minor_and_leaves_the_lower_triangle_alone() -> None:
    matrix = _spd(6)
    matrix[3, 3] = -1.0  # the leading minor of order 4 is not positive definite
    before = np.tril(matrix, -1).copy()
    work = matrix.copy(order="F")
    assert potrf_upper(work) == 4
    np.testing.assert_array_equal(np.tril(work, -1), before)  # no cleaning on failure


def test_potrf_without_cleaning_keeps_the_lower_triangle() -> None:
    matrix = _spd(5)
    work = matrix.copy(order="F")
    assert potrf_upper(work, clean=False) == 0
    np.testing.assert_array_equal(np.tril(work, -1), np.tril(matrix, -1))


def test_a_singular_triangle_is_reported() -> None:
    triangle = np.asfortranarray(np.triu(np.ones((4, 4))))
    triangle[2, 2] = 0.0
    assert trtri_upper(triangle) == 3
    factor = np.asfortranarray(np.triu(np.ones((4, 4))))
    factor[1, 1] = 0.0
    assert potri_upper(factor) == 2


def test_an_empty_matrix_is_a_no_op() -> None:
    assert potrf_upper(np.zeros((0, 0), order="F")) == 0


@pytest.mark.parametrize(
    ("matrix", "message"),
    [
        (np.ones((3, 3), dtype=np.float32, order="F"), "float64"),
        ([[1.0]], "float64"),
        (np.ones((3, 4), order="F"), "square"),
        (np.ones(3), "square"),
        (np.ascontiguousarray(_spd(4) + np.triu(np.ones((4, 4)), 1)), "Fortran"),
        (np.asfortranarray(_spd(8))[::2, ::2], "Fortran"),
    ],
)
def test_bad_arrays_are_refused_before_lapack_sees_them(matrix: object, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        potrf_upper(matrix)  # type: ignore[arg-type]


def test_a_read_only_array_is_refused() -> None:
    matrix = _spd(3)
    matrix.flags.writeable = False
    with pytest.raises(InvalidInputError, match="writable"):
        potri_upper(matrix)


def test_the_gil_is_released_while_lapack_runs() -> None:
    """While another thread is inside ``dpotrf`` (well past its first and before its last
    5 ms), this thread still runs Python: it could not if the call held the GIL. (A call takes
    ~70 ms on a quiet core, longer under load.)"""
    matrix = _spd(2000)
    calls: list[tuple[float, float]] = []

    def factorise() -> None:
        for _ in range(4):
            work = matrix.copy(order="F")
            start = time.perf_counter()
            assert potrf_upper(work, clean=False) == 0
            calls.append((start, time.perf_counter()))

    ticks: list[float] = []
    with threadpool_limits(limits=1):  # one BLAS thread: each call long enough to look inside
        worker = threading.Thread(target=factorise)
        worker.start()
        while worker.is_alive():
            ticks.append(time.perf_counter())
            time.sleep(0.001)
        worker.join()
    margin = 0.005
    inside = [t for t in ticks for start, end in calls if start + margin < t < end - margin]
    long_calls = [end - start for start, end in calls if end - start > 4 * margin]
    assert long_calls, f"the calls were too short to tell: {calls}"
    assert inside, "no Python ran in this thread while dpotrf ran in the other"
