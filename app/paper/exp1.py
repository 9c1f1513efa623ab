"""The paper's Experiment 1, end to end, with our figures beside the paper's.

Composition only: data and fits come from :mod:`core`, the recognition trials from the evaluation
engine (:func:`app.evaluation.runner.run_evaluation`, world ``exp1``, per-trial seeds from the data
seed); this module times them, collects the figures and renders them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from rich.markup import escape
from rich.table import Table

from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from app.paper.calibration import calibration_text
from core.evaluation import (
    Experiment1World,
    TrialRecord,
    abs_correlation,
    sample_dataset,
    summarise,
    wilson_interval,
)
from core.gp import FitOptions, fit_hyperparameters, fit_manifold
from core.recognition import TrialLikelihood
from core.types import ManifoldModel

#: The paper's figures for Experiment 1 (§III-A).
PAPER_CORRELATION = 0.9995
PAPER_RANDOM_CORRELATION = 0.3449


@dataclass
class PolicyFigures:
    """Accuracy of one policy pooled over seeds, and the calibration of its answers
    (:func:`core.evaluation.summary.calibration_summary`, "sure and wrong" at p ≥ 0.95)."""

    accuracy_by_touch: list[float] = field(default_factory=list)
    nearest_accuracy_by_touch: list[float] = field(default_factory=list)
    per_object: list[float] = field(default_factory=list)
    final_interval: list[float] = field(default_factory=list)
    trials: int = 0
    seconds_per_step: float = 0.0
    calibration: dict[str, Any] = field(default_factory=dict)


@dataclass
class Experiment1Figures:
    """Everything ``activetouch paper exp1`` measures."""

    seeds: int
    trials_per_object: int
    max_steps: int
    noise_std: float
    correlations: list[float]
    fit_seconds: list[float]
    random_correlations: list[float]
    policies: dict[str, PolicyFigures]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready figures."""
        out = asdict(self)
        out["median_correlation"] = float(np.median(self.correlations))
        out["median_random_correlation"] = float(np.median(self.random_correlations))
        out["median_fit_seconds"] = float(np.median(self.fit_seconds))
        out["paper"] = {
            "correlation": PAPER_CORRELATION,
            "random_correlation": PAPER_RANDOM_CORRELATION,
        }
        return out

    def table(self) -> Table:
        """A rich table: figure, paper, ours."""
        table = Table(
            title=f"Experiment 1 — {self.seeds:d} data seeds, noise std {self.noise_std:g}, "
            f"T = {self.max_steps:d}, {self.trials_per_object:d} trials per object per seed",
            caption="The paper's figures are from one data set. Our |corr| is that of the "
            "maximum-likelihood optimum: a fit started from S = θ ends at the same point, and "
            "more touches per object do not bring it closer to 1 (python -m bench.corr_vs_data).",
            caption_justify="left",
        )
        table.add_column("figure")
        table.add_column("paper", justify="right")
        table.add_column("ours", justify="right")
        corr = np.asarray(self.correlations)
        rand = np.asarray(self.random_correlations)
        table.add_row(
            "|corr(θ, s)|, learned manifold",
            f"{PAPER_CORRELATION:g}",
            f"median {np.median(corr):.4f} (range {corr.min():.4f}–{corr.max():.4f})",
        )
        table.add_row(
            "|corr(θ, s_w)|, random-latent baseline",
            f"{PAPER_RANDOM_CORRELATION:g}",
            f"median {np.median(rand):.4f} (range {rand.min():.4f}–{rand.max():.4f})",
        )
        table.add_row("fit seconds per data set", "—", f"median {np.median(self.fit_seconds):.2f}")
        for name, figures in self.policies.items():
            curve = " ".join(f"{100 * a:.0f}" for a in figures.accuracy_by_touch)
            table.add_row(
                f"accuracy % by touch 1..T, {escape(name)}",
                "converges to the true object within T = 10" if name == "active" else "—",
                curve,
            )
        for name, figures in self.policies.items():
            table.add_row(
                f"calibration, {escape(name)} (every trial and touch)",
                "—",
                calibration_text({"calibration": figures.calibration}),
            )
        for name, figures in self.policies.items():
            table.add_row(
                f"accuracy at T, {escape(name)} (nearest-latent rule)",
                "—",
                f"{100 * figures.accuracy_by_touch[-1]:.1f}% "
                f"(95 % interval {100 * figures.final_interval[0]:.1f}–"
                f"{100 * figures.final_interval[1]:.1f}) "
                f"({100 * figures.nearest_accuracy_by_touch[-1]:.1f}%), "
                f"{figures.trials:d} trials",
            )
        return table


def run_experiment1(
    seeds: int = 10,
    trials_per_object: int = 5,
    max_steps: int = 10,
    noise_std: float = 0.1,
    restarts: int = 4,
    prior_variance: float = 5.0,
    trial_likelihood: TrialLikelihood = "joint",
    progress: Callable[[str, int], None] | None = None,
) -> Experiment1Figures:
    """Experiment 1 for data seeds 0..seeds-1.

    Per seed: draw 4 × 100 touches (x ~ N(0, 1)), fit the manifold (ds = 1), measure
    |corr(θ, s)|; fit the random-latent baseline (latents drawn from N(0, 1) and held fixed,
    hyperparameters optimised); run ``trials_per_object`` trials per object with the active and
    passive policies on the learned model and the active policy on the baseline, observations
    from the true h, μ0 = mean of S, Σ0 = ``prior_variance``. The trials are an ``exp1``
    evaluation whose seed is the data seed (each trial has its own ``SeedSequence``; the two
    policies see the same noise streams). ``trial_likelihood`` scores each trial's touches
    (:class:`app.evaluation.spec.EvaluationSpec`).
    """
    world = Experiment1World(noise_std=noise_std)
    truth = world.truth[:, 0]
    correlations, fit_seconds, random_correlations = [], [], []
    records: dict[str, list[TrialRecord]] = {
        "active": [],
        "passive": [],
        "random-latent active": [],
    }
    step_seconds: dict[str, list[float]] = {name: [] for name in records}

    def note(message: str, done: int) -> None:
        if progress is not None:
            progress(message, done)

    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        data = sample_dataset(world, rng, touches_per_object=100)
        note(f"seed {seed}: fitting", seed)
        started = time.perf_counter()
        model = fit_manifold(data, 1, rng, FitOptions(restarts=restarts))
        fit_seconds.append(time.perf_counter() - started)
        correlations.append(abs_correlation(truth, model.latents))
        note(f"seed {seed}: random-latent baseline", seed)
        random_latents = rng.standard_normal((data.n_objects, 1))
        baseline = fit_hyperparameters(data, random_latents)
        random_correlations.append(abs_correlation(truth, baseline.latents))
        runs: list[tuple[str, ManifoldModel, str]] = [
            ("active", model, "active"),
            ("passive", model, "passive"),
            ("random-latent active", baseline, "active"),
        ]
        for name, used, policy in runs:
            note(f"seed {seed}: {name} trials", seed)
            spec = EvaluationSpec(
                world="exp1",
                policies=(policy,),
                trials_per_target=trials_per_object,
                steps=max_steps,
                seed=seed,
                noise_std=noise_std,
                prior_variance=prior_variance,
                trial_likelihood=trial_likelihood,
                plan_under="gaussian",  # the paper's planning, as its prior
            )
            report = run_evaluation(used, spec)
            steps = sum(r.touches for r in report.records)
            step_seconds[name].append(report.seconds / max(steps, 1))
            records[name].extend(report.records)
        note(f"seed {seed} done", seed + 1)
    objects = world.object_names
    policies = {}
    for name, mine in records.items():
        [summary] = summarise(mine, objects, max_steps, 0.95).values()
        nearest = [[n == r.target for n in r.nearest_by_touch(max_steps)] for r in mine]
        final = sum(r.correct for r in mine)
        policies[name] = PolicyFigures(
            accuracy_by_touch=summary["accuracy_by_touch"],
            nearest_accuracy_by_touch=np.mean(nearest, axis=0).tolist(),
            per_object=[summary["per_object"][o]["accuracy"] for o in objects],
            final_interval=list(wilson_interval(final, len(mine))),
            trials=len(mine),
            seconds_per_step=float(np.median(step_seconds[name])),
            calibration=summary["calibration"],
        )
    return Experiment1Figures(
        seeds=seeds,
        trials_per_object=trials_per_object,
        max_steps=max_steps,
        noise_std=noise_std,
        correlations=correlations,
        fit_seconds=fit_seconds,
        random_correlations=random_correlations,
        policies=policies,
    )
