"""Benchmark: choosing one action, and the structured moments against the direct formula.

Target: one active action at L = 4, N = 400, dx = 6, dy = 5, ds = 2 in ≤ 50 ms median,
single-threaded. The model is conditioned on an Experiment-2-like world (``core.evaluation.worlds``)
with the true latents, normalised, and fixed hyperparameters, so the figure does not depend on
fitting.

Run: ``.venv/bin/python -m bench.plan_speed [--repeats 50] [--candidates 256] [--refine 2]``
"""

from __future__ import annotations

import os

# Pin BLAS/OpenMP threads before numpy is imported (threadpoolctl is not a dependency).
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from bench.reference_moments import direct_moments_batch  # noqa: E402
from core.evaluation.worlds import random_experiment2_world, sample_dataset  # noqa: E402
from core.gp import condition  # noqa: E402
from core.recognition import (  # noqa: E402
    ActivePolicy,
    Planner,
    action_statistics,
    mutual_information,
    objects_belief,
    predictive_moments,
)
from core.types import GaussianBelief, Hyperparameters, ManifoldModel  # noqa: E402


def build_model(seed: int, touches_per_object: int = 100) -> ManifoldModel:
    """An L=4, N=400, dx=6, dy=5, ds=2 model on an Experiment-2-like world."""
    rng = np.random.default_rng(seed)
    world = random_experiment2_world(rng)
    data = sample_dataset(world, rng, touches_per_object)
    latents = world.latents - world.latents.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum(latents**2, axis=1))))
    latents = latents / spread
    dy, ds, dx = data.observation_dim, latents.shape[1], data.action_dim
    hyper = Hyperparameters(
        signal_variance=np.var(data.observations, axis=0),
        noise_variance=np.full(dy, 0.05**2),
        latent_lengthscales=np.full((dy, ds), world.latent_scale / spread),
        action_lengthscales=np.full((dy, dx), world.action_scale),
    )
    return condition(data, latents, hyper)


def _median_ms(samples: list[float]) -> str:
    values = np.array(samples) * 1e3
    return (
        f"median {np.median(values):7.2f} ms  (p10 {np.percentile(values, 10):6.2f}, "
        f"p90 {np.percentile(values, 90):6.2f}, n={values.size})"
    )


def main() -> None:
    """Print the planning time and the structured-vs-direct comparison."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--candidates", type=int, default=256)
    parser.add_argument("--refine", type=int, default=1)
    parser.add_argument("--direct-actions", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    model = build_model(args.seed)
    rng = np.random.default_rng(args.seed + 1)
    print(
        f"model: L={model.data.n_objects} N={model.data.n_touches} dx={model.data.action_dim} "
        f"dy={model.data.observation_dim} ds={model.latent_dim}; threads pinned to "
        f"{os.environ['OPENBLAS_NUM_THREADS']}"
    )

    start = time.perf_counter()
    planner = Planner(model, ActivePolicy(), n_candidates=args.candidates, n_refine=args.refine)
    setup_s = time.perf_counter() - start
    print(
        f"candidate statistics ({args.candidates} Sobol candidates, once per model): "
        f"{setup_s * 1e3:.1f} ms"
    )

    beliefs = [
        GaussianBelief(
            mean=model.latents[rng.integers(model.data.n_objects)] + 0.3 * rng.standard_normal(2),
            cov=np.diag(rng.uniform(0.05, 5.0, 2)),
        )
        for _ in range(args.repeats)
    ]
    settings = sorted({args.refine, 0, 1, 2})
    results: dict[int, tuple[list[float], list[float], list[float]]] = {}
    for n_refine in settings:
        timed = Planner(model, ActivePolicy(), n_candidates=args.candidates, n_refine=n_refine)
        timed.plan(beliefs[0], rng)  # warm-up (the candidate statistics are built here)
        wall, cpu, values = [], [], []
        for belief in beliefs:
            wall_start, cpu_start = time.perf_counter(), time.process_time()
            planned = timed.plan(belief, rng)
            wall.append(time.perf_counter() - wall_start)
            cpu.append(time.process_time() - cpu_start)
            values.append(planned.mutual_information)
        results[n_refine] = (wall, cpu, values)
    best = np.max([results[n][2] for n in settings], axis=0)
    print(f"plan one action ({args.repeats} beliefs; MI shortfall vs the best setting):")
    for n_refine in settings:
        wall, cpu, values = results[n_refine]
        marker = "  <- the default under the Gaussian" if n_refine == args.refine else ""
        print(
            f"  refine {n_refine}: wall {_median_ms(wall)}; cpu median "
            f"{np.median(cpu) * 1e3:6.2f} ms; MI shortfall median "
            f"{np.median(best - values):.4f}, max {np.max(best - values):.4f} nats{marker}"
        )

    # The default planning: under the mixture over the objects the object posterior implies.
    posteriors = rng.dirichlet(np.full(model.data.n_objects, 0.5), args.repeats)
    mixture_planner = Planner(model, ActivePolicy(), n_candidates=args.candidates)
    mixture_planner.plan(objects_belief(model), rng)  # warm-up
    wall, cpu = [], []
    for posterior in posteriors:
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        mixture_planner.plan(objects_belief(model, posterior), rng)
        wall.append(time.perf_counter() - wall_start)
        cpu.append(time.process_time() - cpu_start)
    print(
        f"  under the objects (the default; {args.repeats} posteriors, candidates only): wall "
        f"{_median_ms(wall)}; cpu median {np.median(cpu) * 1e3:6.2f} ms"
    )

    # Structured vs direct appendix formula on the same actions and belief.
    actions = planner.candidate_statistics.actions[: args.direct_actions]
    belief = beliefs[0]
    start = time.perf_counter()
    ref_mean, ref_cov, ref_cross, ref_mi = direct_moments_batch(model, belief, actions)
    direct_s = (time.perf_counter() - start) / len(actions)
    start = time.perf_counter()
    stats = action_statistics(model, actions)
    moments = predictive_moments(model, belief, stats)
    mi = mutual_information(moments, belief)
    structured_s = (time.perf_counter() - start) / len(actions)
    reps = 200
    start = time.perf_counter()
    for _ in range(reps):
        mi = mutual_information(predictive_moments(model, belief, stats), belief)
    reused_s = (time.perf_counter() - start) / reps / len(actions)

    def rel(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))

    print(
        f"structured vs direct ({len(actions)} actions): max rel. error "
        f"m {rel(moments.mean, ref_mean):.1e}, "
        f"S {rel(moments.cov, ref_cov):.1e}, C {rel(moments.cross_cov, ref_cross):.1e}, "
        f"MI {rel(mi, ref_mi):.1e}"
    )
    print(
        f"per action: direct {direct_s * 1e3:.2f} ms, structured {structured_s * 1e3:.3f} ms "
        f"(x{direct_s / structured_s:.0f}), structured with reused statistics "
        f"{reused_s * 1e6:.2f} us (x{direct_s / reused_s:.0f})"
    )


if __name__ == "__main__":
    main()
