"""The Cholesky factor and the inverse of a symmetric positive definite matrix, at the GEMM rate.

The exact gradient of the manifold likelihood needs every entry of K⁻¹ (docs/method.md (M2)), so
each feature of every evaluation pays for a Cholesky factor A = UᵀU and the inverse from it. The
LAPACK way (``dpotrf``, then ``dpotri`` = ``dtrtri`` + ``dlauum``) spends most of that time in
triangular solves and triangular inversion, which the bundled OpenBLAS runs at a third of its
matrix-product rate on this project's machines (docs/fitting.md, "The factor and the inverse
together"). Here the two are computed together by recursive halving, with every O(n³) step a
triangular product (``dtrmm``) or a symmetric rank-k update (``dsyrk``), both at that rate:

    A = [[A₁₁, A₁₂], [A₁₂ᵀ, A₂₂]],   U = [[U₁₁, U₁₂], [0, U₂₂]],   V = U⁻¹ = [[V₁₁, V₁₂], [0, V₂₂]]

    U₁₁, V₁₁ from A₁₁ (recursively)
    U₁₂ = V₁₁ᵀ A₁₂                     (instead of the solve U₁₁ᵀ U₁₂ = A₁₂)
    U₂₂, V₂₂ from A₂₂ − U₁₂ᵀ U₁₂      (recursively)
    V₁₂ = −V₁₁ U₁₂ V₂₂

and A⁻¹ = V Vᵀ (``dlauum``). Blocks of at most :data:`LEAF_ORDER` go to LAPACK's ``dpotrf`` and
``dtrtri``. The flops are LAPACK's (n³/3 each for the factor, V and V Vᵀ); only the order of the
operations differs, so the results agree with LAPACK's to round-off
(tests/core/test_factor_inverse.py), not bit for bit. Every call goes through SciPy's exported
pointers without the GIL (:mod:`core.gp.unlocked_lapack`), so feature threads run at once.
"""

from __future__ import annotations

import ctypes

import numpy as np

from core.errors import InvalidInputError
from core.gp.unlocked_lapack import checked_square, exported_routine
from core.validation import FloatArray

#: Blocks up to this order are factorised and inverted by LAPACK itself; larger ones by halves.
#: Measured at orders 200-1000 (one thread, interleaved medians): leaves of 64-128 within 3 % of
#: each other, 192 and 256 up to 15 % slower.
LEAF_ORDER = 96

_INT_P = ctypes.POINTER(ctypes.c_int)
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
_CHAR = ctypes.c_char_p
_ADDRESS = ctypes.c_void_p

#: dtrmm(side, uplo, transa, diag, m, n, alpha, a, lda, b, ldb)
_TRMM = ctypes.CFUNCTYPE(
    None, _CHAR, _CHAR, _CHAR, _CHAR, _INT_P, _INT_P, _DOUBLE_P, _ADDRESS, _INT_P, _ADDRESS, _INT_P
)
#: dsyrk(uplo, trans, n, k, alpha, a, lda, beta, c, ldc)
_SYRK = ctypes.CFUNCTYPE(
    None, _CHAR, _CHAR, _INT_P, _INT_P, _DOUBLE_P, _ADDRESS, _INT_P, _DOUBLE_P, _ADDRESS, _INT_P
)
#: dpotrf(uplo, n, a, lda, info)
_POTRF = ctypes.CFUNCTYPE(None, _CHAR, _INT_P, _ADDRESS, _INT_P, _INT_P)
#: dtrtri(uplo, diag, n, a, lda, info)
_TRTRI = ctypes.CFUNCTYPE(None, _CHAR, _CHAR, _INT_P, _ADDRESS, _INT_P, _INT_P)
#: dlauum(uplo, n, a, lda, info)
_LAUUM = _POTRF
#: dlacpy(uplo, m, n, a, lda, b, ldb)
_LACPY = ctypes.CFUNCTYPE(None, _CHAR, _INT_P, _INT_P, _ADDRESS, _INT_P, _ADDRESS, _INT_P)


def factor_and_triangular_inverse(matrix: FloatArray, inverse: FloatArray) -> int:
    """U (A = UᵀU) in place of A's upper triangle, and V = U⁻¹ into ``inverse``'s.

    Args:
        matrix: A, symmetric positive definite; only its upper triangle is read, and only the
            upper triangle is overwritten (with U). Fortran-ordered float64, shape (n, n).
        inverse: Receives V in its upper triangle; its strictly lower triangle is not written
            (pass zeros to get V itself). Fortran-ordered float64, shape (n, n).

    Returns:
        0 on success; k > 0 when the leading minor of order k is not positive definite (as
        LAPACK's ``dpotrf`` reports it). Both arrays then hold partial results.

    Raises:
        InvalidInputError: A wrong dtype, shape or memory order, or the two are one array.
    """
    n = checked_square(matrix, "matrix")
    if checked_square(inverse, "inverse") != n:
        raise InvalidInputError(f"inverse: expected shape {(n, n)}, received {inverse.shape}.")
    if np.shares_memory(matrix, inverse):
        raise InvalidInputError("inverse: must not share memory with matrix.")
    if n == 0:
        return 0
    return _Halving(matrix, inverse).run(0, n)


def spd_inverse(matrix: FloatArray) -> tuple[int, FloatArray]:
    """A⁻¹ of a symmetric positive definite A, with U (A = UᵀU) left in place of A's upper
    triangle (for solves and log det A).

    Args:
        matrix: A (its upper triangle is read and overwritten with U; the strictly lower
            triangle is left as it was). Fortran-ordered float64, shape (n, n).

    Returns:
        LAPACK's info (0, or the order of the first leading minor that is not positive
        definite), and a Fortran-ordered (n, n) array whose upper triangle holds A⁻¹ and whose
        strictly lower triangle is zero (its C-ordered transpose has A⁻¹ in the lower
        triangle), valid when info is 0.
    """
    n = checked_square(matrix, "matrix")
    inverse = np.zeros((n, n), order="F")
    info = factor_and_triangular_inverse(matrix, inverse)
    if info == 0 and n:
        size = ctypes.c_int(n)
        status = ctypes.c_int(0)
        exported_routine("dlauum", _LAUUM)(
            b"U",
            ctypes.byref(size),
            inverse.ctypes.data,
            ctypes.byref(size),
            ctypes.byref(status),
        )  # fails only on bad arguments, checked above
    return info, inverse


class _Halving:
    """The recursion of :func:`factor_and_triangular_inverse` on blocks of two same-order
    Fortran arrays (addresses by offset, so no block is ever copied)."""

    def __init__(self, matrix: FloatArray, inverse: FloatArray) -> None:
        self.n = int(matrix.shape[0])
        self.lda = ctypes.c_int(self.n)
        self.a = int(matrix.ctypes.data)
        self.v = int(inverse.ctypes.data)
        self.arrays = (matrix, inverse)  # alive while their addresses are used
        self.one = ctypes.c_double(1.0)
        self.minus_one = ctypes.c_double(-1.0)
        self.trmm = exported_routine("dtrmm", _TRMM, "blas")
        self.syrk = exported_routine("dsyrk", _SYRK, "blas")
        self.potrf = exported_routine("dpotrf", _POTRF)
        self.trtri = exported_routine("dtrtri", _TRTRI)
        self.lacpy = exported_routine("dlacpy", _LACPY)

    def _at(self, base: int, row: int, column: int) -> int:
        """Address of entry (row, column) of a Fortran (n, n) array at ``base``."""
        return base + 8 * (row + column * self.n)

    def run(self, first: int, order: int) -> int:
        """Factor and invert the diagonal block [first, first + order); info as LAPACK's,
        counted from the whole matrix's first row."""
        by = ctypes.byref
        lda = self.lda
        if order <= LEAF_ORDER:
            size = ctypes.c_int(order)
            status = ctypes.c_int(0)
            self.potrf(b"U", by(size), self._at(self.a, first, first), by(lda), by(status))
            if status.value:
                return first + int(status.value)
            leaf, copy = self._at(self.a, first, first), self._at(self.v, first, first)
            self.lacpy(b"U", by(size), by(size), leaf, by(lda), copy, by(lda))  # U's triangle
            self.trtri(b"U", b"N", by(size), self._at(self.v, first, first), by(lda), by(status))
            return 0  # a successful factor has a positive diagonal, so dtrtri succeeds
        half = order // 32 * 16  # aligned blocks, 0 < half < order
        second = first + half
        info = self.run(first, half)
        if info:
            return info
        rows, columns = ctypes.c_int(half), ctypes.c_int(order - half)
        # U₁₂ = V₁₁ᵀ A₁₂, in place of A₁₂
        self.trmm(
            b"L",
            b"U",
            b"T",
            b"N",
            by(rows),
            by(columns),
            by(self.one),
            self._at(self.v, first, first),
            by(lda),
            self._at(self.a, first, second),
            by(lda),
        )
        # A₂₂ − U₁₂ᵀ U₁₂, in place of A₂₂ (upper triangle)
        self.syrk(
            b"U",
            b"T",
            by(columns),
            by(rows),
            by(self.minus_one),
            self._at(self.a, first, second),
            by(lda),
            by(self.one),
            self._at(self.a, second, second),
            by(lda),
        )
        info = self.run(second, order - half)
        if info:
            return info
        # V₁₂ = −V₁₁ U₁₂ V₂₂
        block, copy = self._at(self.a, first, second), self._at(self.v, first, second)
        self.lacpy(b"A", by(rows), by(columns), block, by(lda), copy, by(lda))  # U₁₂
        self.trmm(
            b"R",
            b"U",
            b"N",
            b"N",
            by(rows),
            by(columns),
            by(self.one),
            self._at(self.v, second, second),
            by(lda),
            self._at(self.v, first, second),
            by(lda),
        )
        self.trmm(
            b"L",
            b"U",
            b"N",
            b"N",
            by(rows),
            by(columns),
            by(self.minus_one),
            self._at(self.v, first, first),
            by(lda),
            self._at(self.v, first, second),
            by(lda),
        )
        return 0
