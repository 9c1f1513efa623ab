"""The inverse and log determinant of a symmetric positive definite matrix, at the GEMM rate,
in place.

The exact gradient of the manifold likelihood needs every entry of K⁻¹ (docs/method.md (M2)), so
each feature of every evaluation pays for a Cholesky factor A = UᵀU and the inverse from it. The
LAPACK way (``dpotrf``, then ``dpotri`` = ``dtrtri`` + ``dlauum``) spends most of that time in
triangular solves and triangular inversion, which the bundled OpenBLAS runs at a third of its
matrix-product rate on this project's machines (docs/fitting.md, "The factor and the inverse
together"). Here the two are computed together by recursive halving, with every O(n³) step a
triangular product (``dtrmm``) or a symmetric rank-k update (``dsyrk``), both at that rate:

    A = [[A₁₁, A₁₂], [A₁₂ᵀ, A₂₂]],   U = [[U₁₁, U₁₂], [0, U₂₂]],   V = U⁻¹ = [[V₁₁, V₁₂], [0, V₂₂]]

    V₁₁ from A₁₁ (recursively, in its place)
    U₁₂ = V₁₁ᵀ A₁₂                     (instead of the solve U₁₁ᵀ U₁₂ = A₁₂; in A₁₂'s place)
    V₂₂ from A₂₂ − U₁₂ᵀ U₁₂           (recursively, in A₂₂'s place)
    V₁₂ = −V₁₁ U₁₂ V₂₂                 (in U₁₂'s place)

and A⁻¹ = V Vᵀ (``dlauum``, in place). Only V's blocks are needed above a block, never U's, so
the whole computation runs in A's own array: no second array and no copies. Blocks of at most
:data:`LEAF_ORDER` go to LAPACK's ``dpotrf`` and ``dtrtri``; U's diagonal is kept from the leaves
for log det A. The flops are LAPACK's (n³/3 each for the factor, V and V Vᵀ); only the order of
the operations differs, so the results agree with LAPACK's to round-off
(tests/core/test_factor_inverse.py), not bit for bit. Every call goes through SciPy's exported
pointers without the GIL (:mod:`core.gp.unlocked_lapack`), so feature threads run at once.
"""

from __future__ import annotations

import ctypes

import numpy as np

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
#: dlaset(uplo, m, n, alpha, beta, a, lda)
_LASET = ctypes.CFUNCTYPE(None, _CHAR, _INT_P, _INT_P, _DOUBLE_P, _DOUBLE_P, _ADDRESS, _INT_P)


def triangular_inverse_of_factor(matrix: FloatArray) -> tuple[int, FloatArray]:
    """V = U⁻¹ (A = UᵀU) in place of A's upper triangle, and U's diagonal.

    Args:
        matrix: A, symmetric positive definite; only its upper triangle is read and
            overwritten (with V), the strictly lower triangle is left as it was.
            Fortran-ordered float64, shape (n, n).

    Returns:
        0 on success, or k > 0 when the leading minor of order k is not positive definite (as
        LAPACK's ``dpotrf`` reports it; the array then holds partial results); and U's
        diagonal, shape (n,) (its entries past a failing leaf are 0).

    Raises:
        InvalidInputError: A wrong dtype, shape or memory order.
    """
    n = checked_square(matrix, "matrix")
    halving = _Halving(matrix)
    info = halving.run(0, n) if n else 0
    return info, halving.diagonal


def spd_inverse(matrix: FloatArray) -> tuple[int, float]:
    """A⁻¹ of a symmetric positive definite A in place of A, and log det A.

    Args:
        matrix: A (only its upper triangle is read). Fortran-ordered float64, shape (n, n).
            Overwritten: on success its upper triangle holds A⁻¹ and its strictly lower
            triangle is zero (so its C-ordered transpose has A⁻¹ in the lower triangle).

    Returns:
        LAPACK's info (0, or the order of the first leading minor that is not positive
        definite; the array then holds partial results), and log det A = 2 Σ log U_ii (NaN
        unless info is 0).
    """
    info, diagonal = triangular_inverse_of_factor(matrix)
    if info:
        return info, float("nan")
    n = matrix.shape[0]
    if n:
        size = ctypes.c_int(n)
        status = ctypes.c_int(0)
        zero = ctypes.c_double(0.0)
        by = ctypes.byref
        exported_routine("dlauum", _LAUUM)(
            b"U", by(size), matrix.ctypes.data, by(size), by(status)
        )  # fails only on bad arguments, checked above
        if n > 1:
            rest = ctypes.c_int(n - 1)
            exported_routine("dlaset", _LASET)(
                b"L", by(rest), by(rest), by(zero), by(zero), matrix.ctypes.data + 8, by(size)
            )
    return 0, 2.0 * float(np.sum(np.log(diagonal)))


class _Halving:
    """The recursion of :func:`triangular_inverse_of_factor` on blocks of one Fortran array
    (addresses by offset, so no block is ever copied)."""

    def __init__(self, matrix: FloatArray) -> None:
        self.n = int(matrix.shape[0])
        self.lda = ctypes.c_int(self.n)
        self.a = int(matrix.ctypes.data)
        self.matrix = matrix  # alive while its address is used
        self.diagonal = np.zeros(self.n)
        self.one = ctypes.c_double(1.0)
        self.minus_one = ctypes.c_double(-1.0)
        self.trmm = exported_routine("dtrmm", _TRMM, "blas")
        self.syrk = exported_routine("dsyrk", _SYRK, "blas")
        self.potrf = exported_routine("dpotrf", _POTRF)
        self.trtri = exported_routine("dtrtri", _TRTRI)

    def _at(self, row: int, column: int) -> int:
        """Address of entry (row, column) of the (n, n) Fortran array."""
        return self.a + 8 * (row + column * self.n)

    def run(self, first: int, order: int) -> int:
        """V of the diagonal block [first, first + order) in its place; info as LAPACK's,
        counted from the whole matrix's first row."""
        by = ctypes.byref
        lda = self.lda
        block = self._at(first, first)
        if order <= LEAF_ORDER:
            size = ctypes.c_int(order)
            status = ctypes.c_int(0)
            self.potrf(b"U", by(size), block, by(lda), by(status))
            if status.value:
                return first + int(status.value)
            stop = first + order
            self.diagonal[first:stop] = self.matrix.diagonal()[first:stop]
            self.trtri(b"U", b"N", by(size), block, by(lda), by(status))
            return 0  # a successful factor has a positive diagonal, so dtrtri succeeds
        half = order // 32 * 16  # aligned blocks, 0 < half < order
        second = first + half
        info = self.run(first, half)
        if info:
            return info
        rows, columns = ctypes.c_int(half), ctypes.c_int(order - half)
        off_diagonal, trailing = self._at(first, second), self._at(second, second)
        # U₁₂ = V₁₁ᵀ A₁₂, in place of A₁₂
        self.trmm(
            b"L",
            b"U",
            b"T",
            b"N",
            by(rows),
            by(columns),
            by(self.one),
            block,
            by(lda),
            off_diagonal,
            by(lda),
        )
        # A₂₂ − U₁₂ᵀ U₁₂, in place of A₂₂ (upper triangle)
        self.syrk(
            b"U",
            b"T",
            by(columns),
            by(rows),
            by(self.minus_one),
            off_diagonal,
            by(lda),
            by(self.one),
            trailing,
            by(lda),
        )
        info = self.run(second, order - half)
        if info:
            return info
        # V₁₂ = −V₁₁ (U₁₂ V₂₂), in place of U₁₂
        self.trmm(
            b"R",
            b"U",
            b"N",
            b"N",
            by(rows),
            by(columns),
            by(self.one),
            trailing,
            by(lda),
            off_diagonal,
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
            block,
            by(lda),
            off_diagonal,
            by(lda),
        )
        return 0
