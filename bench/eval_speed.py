"""Benchmark: the cost of ONE evaluation of -log p and its gradient (docs/method.md eq. (M2)).

Cases (Experiment-2-like world, dx = 6, dy = 5, ds = 2, reference parameters):

* ``dense_L4_N400``: :class:`core.gp.likelihood.ManifoldLikelihood`, random design, L = 4, N = 400;
* ``kron_L4_M100``, ``kron_L100_M100``, ``kron_L400_M100``:
  :class:`core.gp.kronecker.KroneckerLikelihood`, shared design (M = 100 actions per object);

beside GPy's ``_objective_grads`` summed over the five ``GPRegression`` models of the same data
(:mod:`bench.gpy_models`; L = 4 cases only, skipped without GPy) and two floors:

* ``lapack_floor_ms``: the LAPACK calls no exact evaluation avoids, timed alone on the same
  matrices: dense, ``dpotrf`` + ``dpotri`` of every feature's K_a (a factor and the inverse,
  needed for ½ tr(W ∂K)); Kronecker, ``numpy.linalg.eigh`` of every K^s_a and K^x_a;
* ``flop_floor_ms`` (dense): n³/3 + 2n³/3 flops per feature at the GEMM rate measured in the
  same run (LAPACK at N = 400 runs well below the GEMM rate, so this is a loose lower bound).

BLAS threads are pinned (``--threads``, default 1); medians of ``--repeats`` calls.

Run: ``.venv/bin/python -m bench.eval_speed [--repeats 30] [--threads 1] [--cases a,b] [--json]``
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.linalg.lapack

from bench import scenarios
from bench.gpy_models import build_models, load_gpy, value_and_gradient
from bench.harness import blas_threads, gemm_rate, machine, measure
from core.gp.kernels import squared_exponential
from core.gp.kronecker import KroneckerLikelihood
from core.gp.likelihood import ManifoldLikelihood
from core.types import Hyperparameters
from core.validation import FloatArray

#: name -> (design, L, touches per object)
CASES: dict[str, tuple[scenarios.DesignName, int, int]] = {
    "dense_L4_N400": ("random", 4, 100),
    "kron_L4_M100": ("shared", 4, 100),
    "kron_L100_M100": ("shared", 100, 100),
    "kron_L400_M100": ("shared", 400, 100),
}


def _dense_floor(gram_free: FloatArray, noise: FloatArray) -> Callable[[], None]:
    """dpotrf + dpotri of every feature's K_a = K_f,a + σ_n² I."""
    grams = [
        np.asfortranarray(k + s2 * np.eye(k.shape[0]))
        for k, s2 in zip(gram_free, noise, strict=True)
    ]

    def run() -> None:
        for gram in grams:
            upper, _ = scipy.linalg.lapack.dpotrf(gram, lower=0, clean=1)
            scipy.linalg.lapack.dpotri(upper, lower=0, overwrite_c=1)

    return run


def _kronecker_floor(
    latents: FloatArray, design: FloatArray, hyper: Hyperparameters
) -> Callable[[], None]:
    """eigh of every feature's K^s_a and K^x_a."""
    dy = hyper.observation_dim
    latent = np.stack(
        [squared_exponential(latents, latents, hyper.latent_lengthscales[a]) for a in range(dy)]
    )
    action = np.stack(
        [squared_exponential(design, design, hyper.action_lengthscales[a]) for a in range(dy)]
    )

    def run() -> None:
        np.linalg.eigh(latent)
        np.linalg.eigh(action)

    return run


def _case(name: str, repeats: int, with_gpy: bool) -> dict[str, Any]:
    design, n_objects, per_object = CASES[name]
    source = scenarios.world(0, n_objects)
    data = scenarios.dataset(source, design, per_object, 1)
    latents = scenarios.true_latents(source)
    hyper = scenarios.reference_hyperparameters(source, data)
    likelihood: ManifoldLikelihood | KroneckerLikelihood = (
        KroneckerLikelihood(data, 2) if design == "shared" else ManifoldLikelihood(data, 2)
    )
    vector = likelihood.layout.pack(latents, hyper)
    value, _ = likelihood.value_and_gradient(vector)
    # Fewer repeats where one call is long (L = 400: the budget stops after ≥ 1 call).
    both = measure(lambda: likelihood.value_and_gradient(vector), repeats, 2, budget_s=60.0)
    only = measure(lambda: likelihood.value(vector), repeats, 2, budget_s=30.0)
    if isinstance(likelihood, KroneckerLikelihood):
        floor = _kronecker_floor(latents, likelihood.design.actions, hyper)
    else:
        floor = _dense_floor(likelihood.noise_free_gram(vector), hyper.noise_variance)
    lapack = measure(floor, repeats, 1, budget_s=30.0)
    out: dict[str, Any] = {
        "case": name,
        "n_touches": data.n_touches,
        "value": value,
        "value_and_gradient_ms": 1e3 * both.median_s,
        "value_and_gradient_p10_p90_ms": [1e3 * both.p10_s, 1e3 * both.p90_s],
        "value_and_gradient_cpu_ms": 1e3 * both.cpu_median_s,
        "value_ms": 1e3 * only.median_s,
        "lapack_floor_ms": 1e3 * lapack.median_s,
        "lapack_floor_p10_ms": 1e3 * lapack.p10_s,
        "repeats": both.repeats,
    }
    if with_gpy and n_objects <= 4:
        gpy, note = load_gpy()
        if gpy is None:
            out["gpy_note"] = note
        else:
            models = build_models(gpy, data, latents, hyper)
            gpy_value, _ = value_and_gradient(models)
            timing = measure(lambda: value_and_gradient(models), repeats, 2)
            out["gpy_ms"] = 1e3 * timing.median_s
            out["gpy_value"] = gpy_value
            out["speedup_vs_gpy"] = timing.median_s / both.median_s
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated case names")
    parser.add_argument("--no-gpy", action="store_true")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    names = [name for name in args.cases.split(",") if name]
    unknown = [name for name in names if name not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {sorted(CASES)}")
    emit: Callable[[str], None] = (lambda _: None) if args.json else print
    results: dict[str, Any] = {"machine": machine(), "threads": args.threads}
    with blas_threads(args.threads):
        rate = gemm_rate(512)
        results["gemm_gflops"] = rate / 1e9
        n = 400
        floor_s = 5 * (n**3 / 3 + 2 * n**3 / 3) / rate
        results["flop_floor_ms"] = 1e3 * floor_s
        emit(f"{results['machine']['load_average_1_5_15']} load; GEMM {rate / 1e9:.1f} GFLOP/s")
        emit(f"dense FLOP floor (5 potrf + 5 potri at N=400, GEMM rate): {1e3 * floor_s:.2f} ms")
        for name in names:
            row = _case(name, args.repeats, not args.no_gpy)
            results[name] = row
            line = (
                f"{name:16s} N={row['n_touches']:6d}  value+grad "
                f"{row['value_and_gradient_ms']:9.2f} ms "
                f"(p10 {row['value_and_gradient_p10_p90_ms'][0]:.2f}, cpu "
                f"{row['value_and_gradient_cpu_ms']:.2f}, n={row['repeats']})  value "
                f"{row['value_ms']:8.2f} ms  LAPACK floor {row['lapack_floor_ms']:.2f} ms "
                f"(p10 {row['lapack_floor_p10_ms']:.2f})"
            )
            if "gpy_ms" in row:
                line += f"  GPy {row['gpy_ms']:.2f} ms  ({row['speedup_vs_gpy']:.1f}x)"
            emit(line)
    if args.json:
        json.dump(results, sys.stdout)
        print()


if __name__ == "__main__":
    np.seterr(all="raise", under="ignore")
    main()
