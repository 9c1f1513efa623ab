"""Benchmark: the rate of each BLAS/LAPACK routine under a dense evaluation, and the factor and
inverse together (:mod:`core.gp.factor_inverse`) against LAPACK's ``dpotrf`` + ``dpotri``.

For every ``--sizes`` n (BLAS on one thread, medians of ``--repeats`` alternating calls):

* GFLOP/s of ``dgemm`` (2n³), ``dtrmm``, ``dsyrk`` (n³ each), ``dpotrf``, ``dtrtri``, ``dlauum``
  (n³/3 each) and ``dtrsm`` (n³), through SciPy's wrappers on one n × n kernel matrix;
* milliseconds of the factor and the whole inverse: ``dpotrf`` + ``dpotri`` through the
  GIL-free pointers (:mod:`core.gp.unlocked_lapack`), as the likelihood computed them before,
  against :func:`core.gp.factor_inverse.spd_inverse`, and the largest difference of the two
  inverses relative to the largest entry.

Run: ``.venv/bin/python -m bench.lapack_rates [--sizes 400 500 640 800 1000] [--repeats 9]``
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import scipy.linalg.blas as blas
import scipy.linalg.lapack as lapack
from threadpoolctl import threadpool_limits

from bench.harness import machine
from core.gp.factor_inverse import spd_inverse
from core.gp.unlocked_lapack import potrf_upper, potri_upper


def kernel_matrix(n: int, seed: int = 0) -> np.ndarray:
    """A squared-exponential Gram matrix of n random points plus a small ridge (the
    conditioning of a fit's K_a), Fortran-ordered. Shape (n, n)."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(0.0, 4.0, size=(n, 2))
    squared = np.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=2)
    return np.asfortranarray(np.exp(-0.5 * squared) + 1e-3 * np.eye(n))


def _median_ms(calls: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median milliseconds of every call, the calls alternating round by round."""
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            started = time.perf_counter()
            call()
            times[name].append(1e3 * (time.perf_counter() - started))
    return {name: statistics.median(values) for name, values in times.items()}


def lapack_way(matrix: np.ndarray) -> np.ndarray:
    """A⁻¹'s upper triangle by ``dpotrf`` then ``dpotri`` (the likelihood's former path)."""
    work = matrix.copy(order="F")
    if potrf_upper(work) != 0 or potri_upper(work) != 0:
        raise RuntimeError("the benchmark matrix is not positive definite")
    return work


def halving_way(matrix: np.ndarray) -> np.ndarray:
    """A⁻¹'s upper triangle by :func:`core.gp.factor_inverse.spd_inverse`."""
    inverse = matrix.copy(order="F")
    info, _ = spd_inverse(inverse)
    if info != 0:
        raise RuntimeError("the benchmark matrix is not positive definite")
    return inverse


def report(n: int, repeats: int) -> None:
    """Print the rates and the two ways of factor and inverse at order n."""
    matrix = kernel_matrix(n)
    factor, _ = lapack.dpotrf(matrix, lower=0, clean=1)
    other = np.asfortranarray(np.random.default_rng(1).standard_normal((n, n)))
    rates = _median_ms(
        {
            "dgemm": lambda: blas.dgemm(1.0, matrix, other),
            "dtrmm": lambda: blas.dtrmm(1.0, factor, other),
            "dsyrk": lambda: blas.dsyrk(1.0, other),
            "dtrsm": lambda: blas.dtrsm(1.0, factor, other),
            "dpotrf": lambda: lapack.dpotrf(matrix, lower=0),
            "dtrtri": lambda: lapack.dtrtri(factor, lower=0),
            "dlauum": lambda: lapack.dlauum(factor, lower=0),
        },
        repeats,
    )
    flops = {"dgemm": 2.0, "dtrmm": 1.0, "dsyrk": 1.0, "dtrsm": 1.0}
    print(
        f"n = {n}: GFLOP/s "
        + ", ".join(
            f"{name} {flops.get(name, 1 / 3) * n**3 / (ms * 1e6):.0f}" for name, ms in rates.items()
        )
    )
    ways = _median_ms(
        {"lapack": lambda: lapack_way(matrix), "halving": lambda: halving_way(matrix)}, repeats
    )
    old, new = lapack_way(matrix), halving_way(matrix)
    difference = np.abs(np.triu(old) - np.triu(new)).max() / np.abs(old).max()
    print(
        f"    factor and inverse: dpotrf + dpotri {ways['lapack']:.2f} ms, halving "
        f"{ways['halving']:.2f} ms (x{ways['lapack'] / ways['halving']:.2f}); the inverses "
        f"differ by {difference:.1e} of the largest entry"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[400, 500, 640, 800, 1000])
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    print(machine())
    with threadpool_limits(limits=1):
        for n in args.sizes:
            report(n, args.repeats)


if __name__ == "__main__":
    main()
