"""The paper's Experiment 2 on the simulated rig, with our figures beside the paper's.

Composition only: the training touches come from the simulated rig through the loop every
collection uses (:func:`app.services.collections.iter_collection`, DMP actions dx = 6, five
tactile channels), the fit from :mod:`core` (ds = 2, differential evolution), the recognition
trials from the evaluation engine (:func:`app.evaluation.runner.run_evaluation`) twice: with
observations sampled from the learned GP (world ``model``, the paper's protocol) and from the
simulated rig itself (world ``rig``, the honest one). The figures are drawn by
:mod:`app.paper.exp2_figures`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich.markup import escape
from rich.table import Table

from app.evaluation.report import EvaluationReport
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec, Placement
from app.paper.calibration import calibration_text
from app.rig.actions import TouchActions
from app.rig.build import SimulationMode, open_rig
from core.evaluation import random_design
from core.gp import FitOptions, fit_manifold
from core.recognition import EVALUATION_POLICIES
from core.types import ManifoldModel, TrainingData
from hardware.sim.materials import Table as SimTable
from hardware.sim.materials import table_name

#: Observation sources of the recognition trials: the learned GP (the paper's) and the rig.
SOURCES: tuple[str, ...] = ("model", "rig")

#: What the paper reports for Experiment 2 (§III-B, Figs. 9-11); it gives no accuracy figures.
PAPER = {
    "setting": "L = 4 cups, 100 touches each, dx = 6, dy = 5, ds = 2, DE fit, T = 15, "
    "Σ0 = diag(5, 5)",
    "manifold": "O4 (stainless) far from the others (heat); O1 (paper) and O3 (clear) close",
    "active": "converges to the true object (O1) within T = 15 (one trial shown)",
    "passive": "does not converge to the true object within T = 15",
    "actions": "first active touch: FFJ4 a bit stronger, FFJ3 a bit weaker than the teaching",
}

#: Progress callback: (message, fraction of the whole run done in [0, 1]).
Progress = Callable[[str, float], None]


@dataclass(frozen=True)
class Experiment2Settings:
    """What ``activetouch paper exp2`` runs.

    Attributes:
        table: Simulated table: a name (the paper's four cups: ``paper``) or a table read from
            a file (:mod:`hardware.sim.table_file`).
        touches_per_object: Random-design training touches per object (the paper: 100).
        action_scale: Standard deviation of each action component of the design (``None``: the
            table's :attr:`~hardware.sim.materials.Table.action_std`; the paper's cups 0.75 — at
            1 an active touch at the corner of the action box can overload the simulated FFJ3).
        latent_dim: ds (the paper: 2).
        optimizer: Fit optimiser (the paper: differential evolution, ``de``).
        restarts: Random restarts of the fit on top of its data-driven starts.
        steps: T (the paper: 15).
        trials_per_target: Trials per (policy, object) and observation source.
        prior_variance: Σ0 = prior_variance · I (the paper: 5); μ0 = mean of S.
        policies: Policies compared (those of the engine).
        sources: Observation sources (:data:`SOURCES`).
        seed: Seed of the design, the simulated world, the fit and the trials.
        workers: Dask worker processes of the trials (``None``: in process).
        placement: How often a rig trial places its object anew (``"trial"``/``"touch"``,
            :class:`app.evaluation.spec.EvaluationSpec`).
    """

    table: str | SimTable = "paper"
    touches_per_object: int = 100
    action_scale: float | None = None
    latent_dim: int = 2
    optimizer: str = "de"
    restarts: int = 2
    steps: int = 15
    trials_per_target: int = 25
    prior_variance: float = 5.0
    policies: tuple[str, ...] = field(
        default_factory=lambda: tuple(
            p for p in ("active", "discriminative", "passive") if p in EVALUATION_POLICIES
        )
    )
    sources: tuple[str, ...] = SOURCES
    seed: int = 0
    workers: int | None = None
    placement: Placement = "trial"

    @property
    def design_std(self) -> float:
        """The design's spread: ``action_scale``, or the table's own."""
        from hardware.sim.materials import design_std

        return design_std(self.table, self.action_scale)


@dataclass(frozen=True)
class Experiment2Result:
    """Everything one run measured.

    Attributes:
        settings: What was run.
        data: The training touches collected on the simulated rig.
        model: The fitted manifold.
        reports: Evaluation report per observation source.
        collect_seconds: Wall time of the collection.
        fit_seconds: Wall time of the fit.
        seconds: Wall time of the whole run (collection, fit, trials; not the figures).
    """

    settings: Experiment2Settings
    data: TrainingData
    model: ManifoldModel
    reports: dict[str, EvaluationReport]
    collect_seconds: float
    fit_seconds: float
    seconds: float

    def manifold_figures(self) -> dict[str, Any]:
        """Where the objects lie in s: the latents and their pairwise distances."""
        names = self.model.object_names
        s = self.model.latents
        distances = {
            f"{names[i]}/{names[j]}": float(np.linalg.norm(s[i] - s[j]))
            for i in range(len(names))
            for j in range(i + 1, len(names))
        }
        return {
            "latents": {n: s[i].tolist() for i, n in enumerate(names)},
            "distances": distances,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: settings, timings, the manifold and every evaluation report."""
        s = self.settings
        return {
            "format": "activetouch-paper-exp2/1",
            "settings": {
                "table": table_name(s.table),
                "touches_per_object": s.touches_per_object,
                "action_scale": s.design_std,
                "latent_dim": s.latent_dim,
                "optimizer": s.optimizer,
                "restarts": s.restarts,
                "steps": s.steps,
                "trials_per_target": s.trials_per_target,
                "prior_variance": s.prior_variance,
                "policies": list(s.policies),
                "sources": list(s.sources),
                "seed": s.seed,
                "workers": s.workers,
            },
            "collect_seconds": self.collect_seconds,
            "fit_seconds": self.fit_seconds,
            "seconds": self.seconds,
            "manifold": self.manifold_figures(),
            "paper": PAPER,
            "reports": {name: r.to_dict() for name, r in self.reports.items()},
        }

    def table(self) -> Table:
        """A rich table: figure, the paper's, ours."""
        s = self.settings
        table = Table(
            title=f"Experiment 2 on the simulated rig — table {escape(table_name(s.table))}, "
            f"{s.touches_per_object:d} touches per object, ds = {s.latent_dim:d}, "
            f"T = {s.steps:d}, {s.trials_per_target:d} trials per object, policy and source",
            caption="model: observations sampled from the learned GP at the target's latent "
            "(the paper's protocol); rig: every observation a touch of the simulated rig. "
            "Accuracy: the most probable object after each touch; 95 % Wilson intervals. "
            "Calibration over every trial and touch: ECE (expected calibration error), Brier "
            "score, log-loss, and of the answers given with p ≥ the confidence threshold the "
            "wrong ones.",
            caption_justify="left",
        )
        table.add_column("figure")
        table.add_column("paper")
        table.add_column("ours")
        table.add_row("setting", PAPER["setting"], self._setting())
        table.add_row("manifold (Fig. 9)", PAPER["manifold"], self._manifold_text())
        for source, report in self.reports.items():
            summary = report.summary()
            refused_by_policy = report.refused_by_policy()
            for policy in report.spec.policies:
                if policy not in summary:  # no completed trial: every one was refused
                    table.add_row(
                        f"{escape(source)}: {escape(policy)}, accuracy % by touch",
                        PAPER.get(policy, "—") if source == "model" else "—",
                        _all_refused_text(report, policy, refused_by_policy.get(policy, 0)),
                    )
                    continue
                figures = summary[policy]
                curve = " ".join(f"{100 * a:.0f}" for a in figures["accuracy_by_touch"])
                lo, hi = figures["accuracy_interval"][-1]
                paper = PAPER.get(policy, "—") if source == "model" else "—"
                table.add_row(
                    f"{escape(source)}: {escape(policy)}, accuracy % by touch",
                    paper,
                    f"{escape(curve)}\nat T: {100 * figures['accuracy_by_touch'][-1]:.1f} % "
                    f"({100 * lo:.1f}–{100 * hi:.1f})"
                    + _refused_text(figures["trials"], figures.get("refused", 0)),
                )
                per_object = ", ".join(
                    f"{escape(o)} {100 * v['accuracy']:.0f}"
                    for o, v in figures["per_object"].items()
                )
                table.add_row(
                    f"{escape(source)}: {escape(policy)}, per object % at T", "—", per_object
                )
                table.add_row(
                    f"{escape(source)}: {escape(policy)}, calibration",
                    "—",
                    calibration_text(figures),
                )
            table.add_row(f"{escape(source)}: comparison", "—", escape(report.comparison()))
        table.add_row("first actions (Fig. 11)", PAPER["actions"], "see the trajectories figure")
        table.add_row(
            "wall time",
            "—",
            f"{self.seconds:.0f} s (collect {self.collect_seconds:.0f} s, "
            f"fit {self.fit_seconds:.0f} s, trials "
            f"{sum(r.seconds for r in self.reports.values()):.0f} s)",
        )
        return table

    def _setting(self) -> str:
        s = self.settings
        h = self.model.hyperparameters
        return (
            f"L = {self.data.n_objects:d}, {s.touches_per_object:d} touches each, "
            f"dx = {h.action_dim:d} (std {s.design_std:g}), dy = {h.observation_dim:d}, "
            f"ds = {s.latent_dim:d}, {escape(s.optimizer)} fit, T = {s.steps:d}, "
            f"Σ0 = diag({s.prior_variance:g}, …)"
        )

    def _manifold_text(self) -> str:
        figures = self.manifold_figures()
        far = sorted(figures["distances"].items(), key=lambda kv: kv[1])
        closest, farthest = far[0], far[-1]
        return (
            f"closest {escape(closest[0])} ({closest[1]:.2f}), "
            f"farthest {escape(farthest[0])} ({farthest[1]:.2f}) in normalised s"
        )


def collect_training(
    settings: Experiment2Settings,
    actions: TouchActions,
    on_touch: Callable[[int, int], None] | None = None,
) -> TrainingData:
    """Touch every object of the table with a random design through the full simulated rig.

    Args:
        settings: The table, touches per object, action scale and seed.
        actions: The action → trajectory map.
        on_touch: Called with (touches done, touches planned) after each touch.
    """
    from app.services.collections import iter_collection

    handle = open_rig(simulate=SimulationMode.in_process, table=settings.table, seed=settings.seed)
    try:
        slots = {name: slot for slot, name in enumerate(handle.object_names or [])}
        rng = np.random.default_rng(settings.seed)
        dx = actions.action_dim
        plan = random_design(
            len(slots),
            settings.touches_per_object,
            np.zeros(dx),
            settings.design_std**2 * np.eye(dx),
            rng,
        )
        object_index, xs, ys = [], [], []
        order = list(slots)
        with handle.rig.acquire("activetouch paper exp2") as lease:
            lease.connect()
            for touch in iter_collection(lease, actions, slots, plan):
                object_index.append(order.index(touch.object_name))
                xs.append(touch.action)
                ys.append(touch.record.observation)
                if on_touch is not None:
                    on_touch(touch.index + 1, touch.total)
    finally:
        handle.close()
    return TrainingData(
        object_names=tuple(order),
        object_index=np.asarray(object_index, dtype=np.int64),
        actions=np.asarray(xs, dtype=np.float64),
        observations=np.asarray(ys, dtype=np.float64),
    )


def run_experiment2(
    settings: Experiment2Settings,
    progress: Progress | None = None,
) -> Experiment2Result:
    """Collect, fit, and run the recognition trials from both observation sources.

    Args:
        settings: What to run.
        progress: Called with a message and the fraction done (collection 0-0.3, fit 0.3-0.4,
            trials 0.4-1).
    """

    def note(message: str, fraction: float) -> None:
        if progress is not None:
            progress(message, min(max(fraction, 0.0), 1.0))

    started = time.perf_counter()
    actions = TouchActions.from_teaching()
    note("collecting on the simulated rig", 0.0)
    data = collect_training(
        settings,
        actions,
        lambda done, total: note(f"collect: touch {done:d} of {total:d}", 0.3 * done / total),
    )
    collect_seconds = time.perf_counter() - started
    note(f"fitting ds = {settings.latent_dim:d} ({settings.optimizer})", 0.3)
    fit_started = time.perf_counter()
    model = fit_manifold(
        data,
        settings.latent_dim,
        np.random.default_rng(settings.seed),
        FitOptions(optimizer=settings.optimizer, restarts=settings.restarts),  # type: ignore[arg-type]
    )
    fit_seconds = time.perf_counter() - fit_started
    reports: dict[str, EvaluationReport] = {}
    n_sources = len(settings.sources)
    total = len(settings.policies) * len(model.object_names) * settings.trials_per_target
    for k, source in enumerate(settings.sources):
        spec = EvaluationSpec(
            world=source,  # type: ignore[arg-type]
            trials_per_target=settings.trials_per_target,
            steps=settings.steps,
            policies=settings.policies,
            seed=settings.seed,
            table=settings.table if source == "rig" else None,
            prior_variance=settings.prior_variance,
            placement=settings.placement,
            plan_under="gaussian",  # the paper's planning, as its prior
        )
        done = [0]

        def on_trial(
            _record: Any, k: int = k, source: str = source, done: list[int] = done
        ) -> None:
            done[0] += 1
            note(
                f"{source} trials: {done[0]:d} of {total:d}",
                0.4 + 0.6 * (k + done[0] / total) / n_sources,
            )

        reports[source] = run_evaluation(model, spec, workers=settings.workers, on_trial=on_trial)
    note("done", 1.0)
    return Experiment2Result(
        settings=settings,
        data=data,
        model=model,
        reports=reports,
        collect_seconds=collect_seconds,
        fit_seconds=fit_seconds,
        seconds=time.perf_counter() - started,
    )


def write_figures(result: Experiment2Result, directory: Path) -> list[Path]:
    """The manifold (Fig. 9), the first actions' trajectories (Fig. 11), the accuracy curves and
    the reliability diagrams per observation source, as PNGs in ``directory``."""
    from app.paper.exp2_figures import (
        accuracy_figure,
        manifold_figure,
        reliability_figure,
        trajectory_figure,
    )

    directory.mkdir(parents=True, exist_ok=True)
    actions = TouchActions.from_teaching()
    paths = [
        manifold_figure(result.model, directory / "exp2-manifold.png"),
        trajectory_figure(result.reports, actions, directory / "exp2-trajectories.png", touches=5),
    ]
    for source, report in result.reports.items():
        paths.append(accuracy_figure(report, source, directory / f"exp2-accuracy-{source}.png"))
        paths.append(
            reliability_figure(report, source, directory / f"exp2-reliability-{source}.png")
        )
    return paths


def _refused_text(completed: int, refused: int) -> str:
    """ "; 3 refused by the rig (accuracy over the 47 completed)", or nothing."""
    if not refused:
        return ""
    return f"; {refused:d} refused by the rig (accuracy over the {completed:d} completed)"


def _all_refused_text(report: EvaluationReport, policy: str, refused: int) -> str:
    """ "all 8 trials refused by the rig (no accuracy); first: touch 1 of …", or, for a policy
    with no trial at all, "no trials"."""
    if not refused:
        return "no trials"
    first = next(r for r in report.refused if r.policy == policy)
    return (
        f"all {refused:d} trials refused by the rig (no accuracy); first: "
        f"{escape(first.describe())}"
    )
