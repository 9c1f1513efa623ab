"""Benchmark: does ``latent_dim="auto"`` pick the true ds on Experiment-2-like worlds?

For worlds of true ds = 1, 2, 3 (:func:`core.worlds.random_experiment2_world` with
``latent_dim``), sample training touches, run :func:`core.latent_selection.select_latent_dim`
(K-fold cross-validation over touches within objects, candidates 1..4, the best mean held-out
score) with the independent noise model, and print every candidate's held-out score, the
best and the chosen ds, and whether it is the truth.

Run: ``.venv/bin/python -m bench.latent_dim [--seeds 2] [--objects 10] [--touches 15]
[--action-dim 2] [--folds 5] [--restarts 2] [--noise 0.05]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from core.latent_selection import select_latent_dim
from core.manifold import FitOptions, fit_manifold
from core.types import ManifoldModel, TrainingData
from core.worlds import random_experiment2_world, sample_dataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--objects", type=int, default=10)
    parser.add_argument("--touches", type=int, default=15, help="training touches per object")
    parser.add_argument("--action-dim", type=int, default=2)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--restarts", type=int, default=2)
    parser.add_argument("--noise", type=float, default=0.05)
    parser.add_argument("--max-dim", type=int, default=4)
    args = parser.parse_args()
    options = FitOptions(restarts=args.restarts)
    candidates = tuple(range(1, min(args.max_dim, args.objects - 1) + 1))

    def fit(train: TrainingData, ds: int) -> ManifoldModel:
        return fit_manifold(train, ds, np.random.default_rng(0), options, noise_model="independent")

    print(
        f"L={args.objects}, {args.touches} touches per object, dx={args.action_dim}, dy=5, "
        f"noise {args.noise}, {args.folds} folds, candidates {list(candidates)}, "
        f"{args.restarts} restarts"
    )
    print(
        f"{'true':>4s} {'seed':>4s} {'best':>4s} {'chosen':>6s}  scores (mean ± s.e.; paired diff)"
    )
    right = 0
    total = 0
    with threadpool_limits(1):
        for true_dim in (1, 2, 3):
            for seed in range(args.seeds):
                rng = np.random.default_rng(1000 * true_dim + seed)
                world = random_experiment2_world(
                    rng,
                    n_objects=args.objects,
                    latent_dim=true_dim,
                    action_dim=args.action_dim,
                    noise_std=args.noise,
                )
                data = sample_dataset(world, rng, args.touches)
                started = time.perf_counter()
                selection = select_latent_dim(
                    data, fit, np.random.default_rng(seed), candidates, n_folds=args.folds
                )
                scores = "  ".join(
                    f"{c.latent_dim:d}: {c.mean:.3f}±{c.standard_error:.3f} "
                    f"({c.difference:+.3f}±{c.difference_standard_error:.3f})"
                    for c in selection.candidates
                )
                total += 1
                right += selection.chosen == true_dim
                print(
                    f"{true_dim:4d} {seed:4d} {selection.best:4d} {selection.chosen:6d}  {scores}"
                    f"  [{time.perf_counter() - started:.0f} s]",
                    flush=True,
                )
    print(f"chosen = true ds in {right:d} of {total:d} worlds")


if __name__ == "__main__":
    main()
