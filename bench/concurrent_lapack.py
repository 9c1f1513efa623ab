"""Benchmark: do two threads calling LAPACK at once run in parallel?

The dense likelihood can run its features on Python threads (``FitOptions.threads``, docs/fitting.md
"Feature threads"). That pays only if the BLAS/LAPACK library under each call lets two calls from
different threads run at the same time. For each call below this prints the wall time of two threads
each making ``--calls`` calls against the same calls made one after the other (BLAS pinned to one
thread), as a speed-up (median of alternating rounds): ~2 on two free cores when the library runs
concurrent calls in parallel, ~1 when it serialises them.

* ``scipy dpotrf`` / ``scipy dpotri``: SciPy's f2py LAPACK wrappers (its bundled OpenBLAS);
* ``unlocked dpotrf`` / ``unlocked dpotri``: the same routines of the same library through
  SciPy's Cython pointers (:mod:`core.gp.unlocked_lapack`), which release the GIL — the two
  calls of every dense evaluation;
* ``numpy cholesky`` / ``numpy matmul``: NumPy's own OpenBLAS;
* ``scipy dpotrf beside numpy cholesky``: one thread of each, the rate of each against running
  alone — a SciPy call that held the GIL would slow the NumPy thread down.

It also prints one ``dpotrf`` + ``dpotri`` with BLAS on one and on two threads (OpenBLAS's own
threads inside each call), and whether the two agree bit for bit.

Run: ``.venv/bin/python -m bench.concurrent_lapack [--size 800] [--calls 20] [--json]``
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.linalg.lapack
from threadpoolctl import threadpool_info, threadpool_limits

from bench.harness import machine, measure
from core.gp.unlocked_lapack import potrf_upper, potri_upper


def _spd(size: int) -> np.ndarray:
    """A well-conditioned symmetric positive definite matrix. Shape (size, size)."""
    a = np.random.default_rng(0).standard_normal((size, size))
    return np.asarray(a @ a.T / size + np.eye(size), dtype=np.float64)


def _loop(call: Callable[[], object], calls: int) -> None:
    for _ in range(calls):
        call()


def speedup(call: Callable[[], object], calls: int, rounds: int = 3) -> dict[str, float]:
    """Wall seconds of 2 × ``calls`` calls one after the other and on two threads: medians of
    ``rounds`` alternating rounds after one untimed call, and the median of the rounds' ratios."""
    call()
    serials, parallels = [], []
    for _ in range(rounds):
        start = time.perf_counter()
        _loop(call, 2 * calls)
        serials.append(time.perf_counter() - start)
        threads = [threading.Thread(target=_loop, args=(call, calls)) for _ in range(2)]
        start = time.perf_counter()
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        parallels.append(time.perf_counter() - start)
    ratios = [s / p for s, p in zip(serials, parallels, strict=True)]
    return {
        "serial_s": float(np.median(serials)),
        "two_threads_s": float(np.median(parallels)),
        "speedup": float(np.median(ratios)),
    }


def side_by_side(
    first: Callable[[], object], second: Callable[[], object], duration_s: float = 2.0
) -> dict[str, float]:
    """Calls per second of each callable alone and of each beside the other (two threads)."""

    def rate(call: Callable[[], object], out: list[float]) -> None:
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < duration_s:
            call()
            count += 1
        out.append(count / (time.perf_counter() - start))

    alone_first: list[float] = []
    alone_second: list[float] = []
    rate(first, alone_first)
    rate(second, alone_second)
    together_first: list[float] = []
    together_second: list[float] = []
    threads = [
        threading.Thread(target=rate, args=(first, together_first)),
        threading.Thread(target=rate, args=(second, together_second)),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return {
        "first_beside_over_alone": together_first[0] / alone_first[0],
        "second_beside_over_alone": together_second[0] / alone_second[0],
    }


def run(size: int, calls: int) -> dict[str, Any]:
    """Every figure of the module docstring."""
    matrix = _spd(size)
    upper = scipy.linalg.lapack.dpotrf(matrix, lower=0, clean=1)[0]
    calls_by_name: dict[str, Callable[[], object]] = {
        "scipy dpotrf": lambda: scipy.linalg.lapack.dpotrf(matrix, lower=0),
        "scipy dpotri": lambda: scipy.linalg.lapack.dpotri(upper, lower=0),
        "unlocked dpotrf": lambda: potrf_upper(np.asfortranarray(matrix).copy(order="F")),
        "unlocked dpotri": lambda: potri_upper(upper.copy(order="F")),
        "numpy cholesky": lambda: np.linalg.cholesky(matrix),
        "numpy matmul": lambda: matrix @ matrix,
    }
    out: dict[str, Any] = {"size": size, "calls": calls, "machine": machine()}
    out["libraries"] = [
        {key: info.get(key) for key in ("internal_api", "version", "filepath")}
        for info in threadpool_info()
    ]
    with threadpool_limits(1):
        out["two_threads"] = {name: speedup(call, calls) for name, call in calls_by_name.items()}
        out["scipy dpotrf beside numpy cholesky"] = side_by_side(
            calls_by_name["scipy dpotrf"], calls_by_name["numpy cholesky"]
        )

    def factor_and_inverse() -> np.ndarray:
        factor = scipy.linalg.lapack.dpotrf(matrix, lower=0, clean=1)[0]
        return np.asarray(scipy.linalg.lapack.dpotri(factor, lower=0)[0])

    results = {}
    for blas in (1, 2):
        with threadpool_limits(blas):
            out[f"dpotrf+dpotri ms, BLAS on {blas}"] = (
                measure(factor_and_inverse, repeats=15).median_s * 1e3
            )
            results[blas] = factor_and_inverse()
    out["BLAS 1 and 2 bit-identical"] = bool(np.array_equal(results[1], results[2]))
    out["BLAS 1 vs 2 max difference"] = float(np.max(np.abs(results[1] - results[2])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=800)
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    out = run(args.size, args.calls)
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"N = {args.size}, {args.calls} calls per thread")
    for library in out["libraries"]:
        print(f"  {library['internal_api']} {library['version']}: {library['filepath']}")
    print("two threads against one after the other (BLAS on one thread each):")
    for name, figures in out["two_threads"].items():
        print(
            f"  {name:17s} serial {figures['serial_s']:.3f} s, two threads "
            f"{figures['two_threads_s']:.3f} s: x{figures['speedup']:.2f}"
        )
    beside = out["scipy dpotrf beside numpy cholesky"]
    print(
        "scipy dpotrf beside numpy cholesky, rate against alone: "
        f"scipy {beside['first_beside_over_alone']:.2f}, "
        f"numpy {beside['second_beside_over_alone']:.2f}"
    )
    for blas in (1, 2):
        print(f"dpotrf + dpotri, BLAS on {blas} thread(s): "
              f"{out[f'dpotrf+dpotri ms, BLAS on {blas}']:.1f} ms")  # fmt: skip
    print(
        f"BLAS on 1 and 2 threads bit-identical: {out['BLAS 1 and 2 bit-identical']} "
        f"(max difference {out['BLAS 1 vs 2 max difference']:.1e})"
    )


if __name__ == "__main__":
    main()
