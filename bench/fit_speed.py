"""Benchmark: manifold fitting on Experiment 1 (|corr| over data seeds) and one-start cost.

For each data seed of Experiment 1 (4 objects × 100 touches, dx=1, dy=3, ds=1) it fits the
manifold with the default :class:`core.gp.manifold.FitOptions` and prints |corr(θ, s)|, the fit
time and the log-likelihood, beside the log-likelihood with the true θ as fixed latents
(hyperparameters fitted); then the paper's random-latent baseline (random S_w held fixed,
hyperparameters fitted with :func:`core.gp.manifold.fit_hyperparameters`). With ``--one-start`` it
also times one L-BFGS start on all the data at L=4, N=400, dx=6, dy=5, ds=2.

Wall-clock seconds depend on what else runs on the machine; the CPU seconds of the process
(all threads) are what the fit costs on an otherwise idle core. BLAS threads are limited to
``--threads`` (default 1): on 2 shared cores, threaded LAPACK
(``dpotri`` in particular) slows down by 10-100x whenever the other core is busy.

Run: ``.venv/bin/python -m bench.fit_speed [--seeds 10] [--noise-std 0.1] [--one-start]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from bench.reference_fit import joint_optimum
from core.evaluation import abs_correlation, procrustes_r2
from core.evaluation.worlds import (
    EXPERIMENT1_THETAS,
    random_experiment2_world,
    sample_dataset,
    sample_experiment1,
)
from core.gp import FitOptions, fit_hyperparameters, fit_manifold
from core.gp.fit_run import FitRun
from core.gp.initialisation import pca_latents, random_latents
from core.gp.likelihood import ManifoldLikelihood
from core.gp.parameters import initial_hyperparameters
from core.types import ManifoldModel, TrainingData


def experiment1(seeds: int, noise_std: float, options: FitOptions) -> None:
    theta = np.array(EXPERIMENT1_THETAS)
    print(f"Experiment 1, noise std {noise_std}, {options.optimizer}, restarts {options.restarts}")
    print(
        "seed  |corr|   fit_s  cpu_s  log_lik  true-θ log_lik  from-θ log_lik |corr|  best  "
        "full_evals screen_evals  random-latent |corr|"
    )
    corrs, times, cpus, baseline, truth_basin = [], [], [], [], []
    for seed in range(seeds):
        data = sample_experiment1(np.random.default_rng(seed), noise_std=noise_std)
        start = time.perf_counter()
        cpu_start = time.process_time()
        run = FitRun(data, 1, np.random.default_rng(1000 + seed), options)
        model = None
        for event in run.events():
            model = event.model if event.model is not None else model
        elapsed = time.perf_counter() - start
        cpu = time.process_time() - cpu_start
        assert model is not None
        assert model.diagnostics is not None
        corr = abs_correlation(theta, model.latents)
        random_s = random_latents(4, 1, np.random.default_rng(2000 + seed))
        fixed = fit_hyperparameters(data, random_s)
        corr_random = abs_correlation(theta, fixed.latents)
        # The true θ as fixed latents, hyperparameters fitted: if this is below the fit's
        # log-likelihood, a |corr| short of 1 is the maximum-likelihood answer, not a failure
        # of the optimiser.
        oracle_model = fit_hyperparameters(data, theta[:, None])
        oracle = oracle_model.log_likelihood
        # ... and the optimum reached from the truth: the joint fit started at S = θ (with
        # those hyperparameters). If it is the fit's optimum, no optimiser can do better on
        # |corr| without changing the estimator.
        from_truth, from_truth_corr = _fit_from(data, oracle_model, options)
        screen = run.screen.likelihood.evaluations if run.screen is not None else 0
        print(
            f"{seed:4d}  {corr:.5f}  {elapsed:5.2f}  {cpu:5.2f}  {model.log_likelihood:8.2f}  "
            f"{oracle:13.2f}  {from_truth:13.2f} {from_truth_corr:.5f}  "
            f"{model.diagnostics.best_start:4d}  {run.full.likelihood.evaluations:10d} "
            f"{screen:12d}  {corr_random:.3f} (log_lik {fixed.log_likelihood:.1f})"
        )
        corrs.append(corr)
        times.append(elapsed)
        cpus.append(cpu)
        baseline.append(corr_random)
        truth_basin.append(from_truth_corr)
    print(
        f"median |corr| {np.median(corrs):.5f} (min {min(corrs):.5f}, max {max(corrs):.5f}); "
        f"fit seconds median {np.median(times):.2f}, max {max(times):.2f} (CPU seconds median "
        f"{np.median(cpus):.2f}, max {max(cpus):.2f}); "
        f"random-latent median |corr| {np.median(baseline):.3f}; "
        f"from-θ optimum median |corr| {np.median(truth_basin):.5f}"
    )


def _fit_from(data: TrainingData, start: ManifoldModel, options: FitOptions) -> tuple[float, float]:
    """Log-likelihood and |corr(θ, s)| of the joint L-BFGS-B optimum reached from ``start``."""
    log_likelihood, latents = joint_optimum(data, start, options)
    return log_likelihood, abs_correlation(np.array(EXPERIMENT1_THETAS), latents)


def one_start(seed: int = 0) -> None:
    """One fit start (``restarts=0``) on all the data at L=4, N=400, dx=6, dy=5, ds=2."""
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(rng)
    data = sample_dataset(world, rng, touches_per_object=100)
    likelihood = ManifoldLikelihood(data, 2)
    vector = likelihood.layout.pack(pca_latents(data, 2, rng), initial_hyperparameters(data, 2))
    ts = []
    for _ in range(10):
        t0 = time.perf_counter()
        likelihood.value_and_gradient(vector)
        ts.append(time.perf_counter() - t0)
    start = time.perf_counter()
    model = fit_manifold(data, 2, rng, FitOptions(restarts=0))
    elapsed = time.perf_counter() - start
    iterations = model.diagnostics.iterations if model.diagnostics else 0
    print(
        f"Benchmark shape (L=4, N=400, dx=6, dy=5, ds=2): value+gradient median "
        f"{1e3 * np.median(ts):.1f} ms; one start {elapsed:.2f} s, {iterations} iterations, "
        f"log_lik {model.log_likelihood:.2f}, Procrustes R² to the true latents "
        f"{procrustes_r2(world.truth, model.latents):.4f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--noise-std", type=float, default=0.1)
    parser.add_argument("--restarts", type=int, default=FitOptions().restarts)
    parser.add_argument("--optimizer", choices=("lbfgs", "de"), default="lbfgs")
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads")
    parser.add_argument("--one-start", action="store_true", help="also time one start at N=400")
    parser.add_argument("--stall-relative", type=float, default=FitOptions().stall_relative)
    args = parser.parse_args()
    options = FitOptions(
        optimizer=args.optimizer, restarts=args.restarts, stall_relative=args.stall_relative
    )
    with threadpool_limits(limits=args.threads):
        experiment1(args.seeds, args.noise_std, options)
        if args.one_start:
            one_start()


if __name__ == "__main__":
    main()
