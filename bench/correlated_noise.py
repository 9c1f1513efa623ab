"""Benchmark: correlated channel noise — recognition, held-out likelihood and calibration.

On the correlated-noise world (:func:`core.evaluation.worlds.correlated_noise_world`:
five tactile-like channels on scales 100…1 whose noise correlates up to 0.8, noise comparable to
the differences between objects) and on Experiment-2-like worlds (independent noise), every model
is fitted on training touches and judged on fresh held-out touches of the same objects:

* held-out predictive log-likelihood per touch, log p(y | s_l, x) under the touch's own object
  (raw units, Jacobian included; for the centroid classifier its Gaussian density);
* recognition after 1 and 3 touches: groups of held-out touches of one object, answered by the
  object posterior (the argmax of p(l | touches));
* calibration: of the answers given with probability ≥ 0.95, the fraction right, and a
  reliability table (bins of the answer's probability vs the observed accuracy).

Models: ``centroid`` (Gaussian nearest centroid: per-object mean, one pooled full covariance, on
the raw features, the action ignored), ``independent`` (standardised features, independent noise
per feature: the old M1), ``within-object`` (whitened by the pooled within-object covariance, the
quick fix), ``correlated`` (whitened by the residual noise covariance of a first fit, refitted:
the new model) and ``auto`` (what ``noise_model="auto"`` keeps).

Run: ``.venv/bin/python -m bench.correlated_noise [--seeds 3] [--objects 6] [--touches 40]
[--test-touches 20] [--groups 40] [--noise 0.3] [--exp2-seeds 3]``
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.stats
from threadpoolctl import threadpool_limits

from core.evaluation.worlds import correlated_noise_world, random_experiment2_world, sample_dataset
from core.gp import FitOptions, fit_manifold
from core.gp.noise_model import (
    attach_transform,
    choose_noise_model,
    transform_data,
    within_object_transform,
)
from core.recognition import object_log_likelihoods, touch_log_likelihoods
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray

#: Upper edges of the reliability bins of the answer's probability.
BIN_EDGES = (0.5, 0.8, 0.95, 0.99, 1.0)


@dataclasses.dataclass
class Tally:
    """Answers of one model: (touches, probability of the answer, right) for every group."""

    held_out: list[float] = dataclasses.field(default_factory=list)
    answers: list[tuple[int, float, bool]] = dataclasses.field(default_factory=list)

    def accuracy(self, touches: int) -> float:
        right = [r for k, _, r in self.answers if k == touches]
        return float(np.mean(right))

    def confident(self, threshold: float = 0.95) -> tuple[int, float]:
        right = [r for _, p, r in self.answers if p >= threshold]
        return len(right), float(np.mean(right)) if right else float("nan")


LogLikelihoods = Callable[[FloatArray, FloatArray], FloatArray]


def centroid_classifier(train: TrainingData) -> tuple[LogLikelihoods, Callable[..., FloatArray]]:
    """Gaussian nearest centroid with one pooled full covariance (raw features, x ignored)."""
    y = train.observations
    means = np.array([y[train.object_index == o].mean(axis=0) for o in range(train.n_objects)])
    centred = y - means[train.object_index]
    pooled = centred.T @ centred / (train.n_touches - train.n_objects)

    def per_object(actions: FloatArray, observations: FloatArray) -> FloatArray:
        del actions
        return np.array(
            [
                scipy.stats.multivariate_normal(means[o], pooled).logpdf(observations).sum()
                for o in range(train.n_objects)
            ]
        )

    def per_touch(index: FloatArray, actions: FloatArray, observations: FloatArray) -> FloatArray:
        del actions
        return np.array(
            [
                scipy.stats.multivariate_normal(means[o], pooled).logpdf(y_t)
                for o, y_t in zip(index, observations, strict=True)
            ]
        )

    return per_object, per_touch


def model_scorers(model: ManifoldModel) -> tuple[LogLikelihoods, Callable[..., FloatArray]]:
    return (
        lambda x, y: object_log_likelihoods(model, x, y),
        lambda index, x, y: touch_log_likelihoods(model, index, x, y),
    )


def evaluate(
    tally: Tally,
    scorers: tuple[LogLikelihoods, Callable[..., FloatArray]],
    test: TrainingData,
    groups: int,
    seed: int,
) -> None:
    per_object, per_touch = scorers
    tally.held_out.append(
        float(per_touch(test.object_index, test.actions, test.observations).mean())
    )
    for touches in (1, 3):
        rng = np.random.default_rng(seed + 1000 * touches)  # the same groups for every model
        for obj in range(test.n_objects):
            pool = np.flatnonzero(test.object_index == obj)
            for _ in range(groups):
                pick = rng.choice(pool, touches, replace=False)
                log_like = per_object(test.actions[pick], test.observations[pick])
                probabilities = np.exp(log_like - log_like.max())
                probabilities /= probabilities.sum()
                answer = int(np.argmax(probabilities))
                tally.answers.append((touches, float(probabilities[answer]), answer == obj))


def fit_all(train: TrainingData, latent_dim: int, options: FitOptions) -> dict[str, ManifoldModel]:
    rng = np.random.default_rng(0)
    independent = fit_manifold(train, latent_dim, rng, options, noise_model="independent")
    correlated = fit_manifold(train, latent_dim, rng, options, noise_model="correlated")
    within = within_object_transform(train)
    within_model = attach_transform(
        fit_manifold(transform_data(train, within), latent_dim, rng, options), within, train
    )
    return {
        "independent": independent,
        "within-object": within_model,
        "correlated": correlated,
        "auto": choose_noise_model(independent, correlated),
    }


def reliability(tally: Tally) -> list[str]:
    rows = []
    low = 0.0
    for high in BIN_EDGES:
        inside = [r for _, p, r in tally.answers if low <= p < high or (high == 1.0 and p == 1.0)]
        mean_p = [p for _, p, _ in tally.answers if low <= p < high or (high == 1.0 and p == 1.0)]
        if inside:
            rows.append(
                f"    [{low:.2f}, {high:.2f}{']' if high == 1.0 else ')'}  n={len(inside):5d}  "
                f"mean p={np.mean(mean_p):.3f}  accuracy={np.mean(inside):.3f}"
            )
        low = high
    return rows


def report(title: str, tallies: dict[str, Tally]) -> None:
    print(f"\n{title}")
    print(
        f"  {'model':<14s} {'held-out ll/touch':>18s} {'1 touch':>8s} {'3 touches':>10s} "
        f"{'p≥0.95: n':>10s} {'right':>7s}"
    )
    for name, tally in tallies.items():
        n, right = tally.confident()
        print(
            f"  {name:<14s} {np.mean(tally.held_out):18.3f} {100 * tally.accuracy(1):7.1f}% "
            f"{100 * tally.accuracy(3):9.1f}% {n:10d} {100 * right:6.1f}%"
        )
    for name, tally in tallies.items():
        print(f"  reliability, {name} (answer's probability vs accuracy):")
        for row in reliability(tally):
            print(row)


MODELS = ("centroid", "independent", "within-object", "correlated", "auto")


def compare(
    make_world: Callable[[np.random.Generator], Any],
    n_seeds: int,
    rng_offset: int,
    latent_dim: int,
    args: argparse.Namespace,
    options: FitOptions,
) -> tuple[dict[str, Tally], list[str], float]:
    """Fit every model of :data:`MODELS` on worlds ``make_world(rng)`` (``rng`` seeded
    ``rng_offset + seed`` for each of ``n_seeds`` seeds) and score them on held-out touches.

    Returns:
        The tallies by model, the noise model each ``auto`` fit kept, and the seconds taken.
    """
    tallies = {name: Tally() for name in MODELS}
    chosen: list[str] = []
    started = time.perf_counter()
    for seed in range(n_seeds):
        rng = np.random.default_rng(rng_offset + seed)
        world = make_world(rng)
        train = sample_dataset(world, rng, args.touches)
        test = sample_dataset(world, rng, args.test_touches)
        models = fit_all(train, latent_dim, options)
        auto = models["auto"].transform
        chosen.append(auto.kind if auto is not None else "identity")
        evaluate(tallies["centroid"], centroid_classifier(train), test, args.groups, seed)
        for name, model in models.items():
            evaluate(tallies[name], model_scorers(model), test, args.groups, seed)
    return tallies, chosen, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="correlated worlds")
    parser.add_argument("--objects", type=int, default=6)
    parser.add_argument("--latent-dim", type=int, default=2)
    parser.add_argument("--touches", type=int, default=40, help="training touches per object")
    parser.add_argument("--test-touches", type=int, default=20, help="held-out per object")
    parser.add_argument("--groups", type=int, default=40, help="test groups per object and size")
    parser.add_argument("--noise", type=float, default=0.3, help="noise std (unscaled units)")
    parser.add_argument("--exp2-seeds", type=int, default=3, help="Experiment-2-like worlds")
    parser.add_argument("--exp2-noise", type=float, default=0.2, help="their noise std")
    parser.add_argument("--restarts", type=int, default=2)
    args = parser.parse_args()
    options = FitOptions(restarts=args.restarts)
    with threadpool_limits(1):
        tallies, chosen, seconds = compare(
            lambda rng: correlated_noise_world(
                rng, n_objects=args.objects, latent_dim=args.latent_dim, noise_std=args.noise
            ),
            args.seeds,
            0,
            args.latent_dim,
            args,
            options,
        )
        report(
            f"correlated-noise world: {args.seeds} seeds, L={args.objects}, ds={args.latent_dim}, "
            f"dx=1, dy=5, {args.touches} training + {args.test_touches} held-out touches per "
            f"object, noise std {args.noise} (x channel scale), {args.groups} groups per object "
            f"and size; auto kept {chosen}; {seconds:.0f} s",
            tallies,
        )
        tallies, chosen, seconds = compare(
            lambda rng: random_experiment2_world(
                rng, n_objects=args.objects, action_dim=2, noise_std=args.exp2_noise
            ),
            args.exp2_seeds,
            100,
            2,
            args,
            options,
        )
        report(
            f"Experiment-2-like worlds (independent noise {args.exp2_noise}, ds=2, dx=2, dy=5): "
            f"{args.exp2_seeds} seeds, L={args.objects}; auto kept {chosen}; {seconds:.0f} s",
            tallies,
        )


if __name__ == "__main__":
    main()
