"""LAPACK's O(n³) triangular routines (and the BLAS-3 ones under them) called without the GIL.

SciPy's f2py wrappers (``scipy.linalg.lapack.dpotrf`` and the rest) keep the GIL for the whole
call, so the feature threads of one likelihood evaluation (:mod:`core.gp.likelihood`,
``FitOptions.threads``) factorised one feature after another however many threads there were.
SciPy also exports the same LAPACK, from the same bundled library, as C function pointers for
Cython (``scipy.linalg.cython_lapack.__pyx_capi__``, the route Numba takes); a ``ctypes`` call
through such a pointer releases the GIL. The results are bit for bit those of the f2py
wrappers: the same routine of the same library on the same bytes
(tests/core/test_unlocked_lapack.py).

Every function works in place on a Fortran-ordered float64 square matrix and returns LAPACK's
``info``; only the upper triangle is read and written (the strictly lower one is left as it
was). Arguments are checked before the call, since LAPACK would read or write out of bounds
on a wrong shape or order.

Measured (docs/fitting.md, "Feature threads"): two threads each factorising and inverting
800 × 800 matrices ran 1.5-1.8x faster than one thread doing both, against 0.9-1.2x through
the f2py wrappers.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import cython_blas, cython_lapack

from core.errors import InvalidInputError
from core.validation import FloatArray

_INT_P = ctypes.POINTER(ctypes.c_int)

#: void f(char *uplo, int *n, double *a, int *lda, int *info)
_UPLO_N_A_LDA_INFO = ctypes.CFUNCTYPE(
    None, ctypes.c_char_p, _INT_P, ctypes.c_void_p, _INT_P, _INT_P
)
#: void f(char *uplo, char *diag, int *n, double *a, int *lda, int *info)
_UPLO_DIAG_N_A_LDA_INFO = ctypes.CFUNCTYPE(
    None, ctypes.c_char_p, ctypes.c_char_p, _INT_P, ctypes.c_void_p, _INT_P, _INT_P
)


@functools.cache
def exported_routine(name: str, prototype: Any, library: str = "lapack") -> Callable[..., None]:
    """The ctypes function of ``cython_lapack``'s (or, with ``library="blas"``,
    ``cython_blas``'s) exported pointer ``name``."""
    module = cython_blas if library == "blas" else cython_lapack
    capsule = module.__pyx_capi__[name]
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype = ctypes.c_char_p
    get_name.argtypes = [ctypes.py_object]
    get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
    get_pointer.restype = ctypes.c_void_p
    get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    address = get_pointer(capsule, get_name(capsule))
    return prototype(address)  # type: ignore[no-any-return]


def checked_square(matrix: FloatArray, what: str) -> int:
    """The order n of ``matrix``, which must be an (n, n) writable Fortran-ordered float64
    array (what LAPACK may overwrite in place)."""
    if not isinstance(matrix, np.ndarray) or matrix.dtype != np.float64:
        raise InvalidInputError(f"{what}: expected a float64 array, received {type(matrix)}.")
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1]:
        raise InvalidInputError(f"{what}: expected a square matrix, received {matrix.shape}.")
    if not matrix.flags.f_contiguous or not matrix.flags.writeable:
        raise InvalidInputError(f"{what}: expected a writable Fortran-ordered array.")
    if matrix.shape[0] > np.iinfo(np.int32).max:  # pragma: no cover - LAPACK's int
        raise InvalidInputError(f"{what}: order {matrix.shape[0]} is beyond LAPACK's int.")
    return int(matrix.shape[0])


def _call_uplo(name: str, matrix: FloatArray) -> int:
    n = ctypes.c_int(checked_square(matrix, name))
    info = ctypes.c_int(0)
    if n.value:
        routine = exported_routine(name, _UPLO_N_A_LDA_INFO)
        routine(b"U", ctypes.byref(n), matrix.ctypes.data, ctypes.byref(n), ctypes.byref(info))
    return int(info.value)


def potrf_upper(matrix: FloatArray, clean: bool = True) -> int:
    """``dpotrf``: the upper Cholesky factor U (A = UᵀU) in place of A's upper triangle.

    Args:
        matrix: A, symmetric positive definite (its upper triangle is read), Fortran-ordered
            float64. Shape (n, n).
        clean: Also set the strictly lower triangle to zero (on success), so that ``matrix``
            is U itself, as ``scipy.linalg.lapack.dpotrf(..., clean=1)`` leaves it.

    Returns:
        LAPACK's info: 0 on success, k > 0 when the leading minor of order k is not positive
        definite (the factor is then incomplete).
    """
    info = _call_uplo("dpotrf", matrix)
    if clean and info == 0 and matrix.shape[0] > 1:
        np.multiply(matrix, _upper_mask(matrix.shape[0]), out=matrix)
    return info


@functools.lru_cache(maxsize=8)
def _upper_mask(n: int) -> FloatArray:
    """1.0 on and above the diagonal, 0.0 below, Fortran-ordered. Shape (n, n)."""
    mask = np.triu(np.ones((n, n)))
    mask.flags.writeable = False
    return np.asfortranarray(mask)


def potri_upper(matrix: FloatArray) -> int:
    """``dpotri``: A⁻¹'s upper triangle in place of the upper factor U of A = UᵀU.

    Returns:
        LAPACK's info: 0 on success, k > 0 when U's k-th diagonal entry is zero.
    """
    return _call_uplo("dpotri", matrix)


def lauum_upper(matrix: FloatArray) -> int:
    """``dlauum``: the upper triangle of V Vᵀ in place of an upper-triangular V."""
    return _call_uplo("dlauum", matrix)


def trtri_upper(matrix: FloatArray) -> int:
    """``dtrtri`` (non-unit diagonal): U⁻¹ in place of an upper-triangular U.

    Returns:
        LAPACK's info: 0 on success, k > 0 when U's k-th diagonal entry is zero.
    """
    n = ctypes.c_int(checked_square(matrix, "dtrtri"))
    info = ctypes.c_int(0)
    if n.value:
        routine = exported_routine("dtrtri", _UPLO_DIAG_N_A_LDA_INFO)
        routine(
            b"U", b"N", ctypes.byref(n), matrix.ctypes.data, ctypes.byref(n), ctypes.byref(info)
        )
    return int(info.value)
