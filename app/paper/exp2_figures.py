"""The figures of ``activetouch paper exp2`` as PNGs (matplotlib, Agg).

* :func:`manifold_figure` — the objects in s with the spread of their training touches (the
  paper's Fig. 9): each training touch placed where one touch alone puts the belief (the
  Gaussian update of docs/method.md (M5) from the prior μ0 = mean of S, Σ0), coloured by object.
* :func:`trajectory_figure` — the joint trajectories (FFJ3, FFJ4) of the first actions chosen in
  one trial per policy beside the teaching trajectory (the paper's Fig. 11).
* :func:`accuracy_figure` — accuracy by touch with the 95 % Wilson intervals, per policy.
* :func:`reliability_figure` — the reliability diagram of each policy's answers
  (:func:`app.evaluation.plot.draw_reliability`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from core.types import ManifoldModel

if TYPE_CHECKING:
    from app.evaluation.report import EvaluationReport
    from app.rig.actions import TouchActions


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> Path:
    """Lay ``fig`` out, write it to ``path`` and free it; returns ``path``."""
    fig.tight_layout()
    fig.savefig(path)
    _pyplot().close(fig)
    return path


def one_touch_latents(model: ManifoldModel, prior_variance: float = 5.0) -> np.ndarray:
    """Where each training touch alone places the belief mean. Shape (N, ds).

    One Gaussian update (docs/method.md (M5)) of the prior μ0 = mean of S, Σ0 = prior_variance · I
    with the touch's (x, y).
    """
    from core.recognition import action_statistics, default_prior, predictive_moments, update_belief

    prior = default_prior(model, prior_variance)
    data = model.data
    stats = action_statistics(model, data.actions)
    moments = predictive_moments(model, prior, stats)
    ys = model.to_model_space(data.observations)
    return np.array([update_belief(prior, moments, i, ys[i]).mean for i in range(data.n_touches)])


def manifold_figure(model: ManifoldModel, path: Path, prior_variance: float = 5.0) -> Path:
    """The learned latents S with the one-touch beliefs of the training touches (Fig. 9)."""
    plt = _pyplot()
    s = model.latents
    touches = one_touch_latents(model, prior_variance)
    index = model.data.object_index
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    colours = plt.get_cmap("tab10")
    for k, name in enumerate(model.object_names):
        mine = touches[index == k]
        y_of = (lambda a: a[:, 1]) if model.latent_dim > 1 else (lambda a: np.zeros(len(a)))
        ax.scatter(mine[:, 0], y_of(mine), s=6, alpha=0.35, color=colours(k % 10))
        ax.scatter(
            s[k, 0],
            s[k, 1] if model.latent_dim > 1 else 0.0,
            s=120,
            marker="*",
            edgecolor="black",
            color=colours(k % 10),
            label=f"O{k + 1}: {name}",
            zorder=3,
        )
    ax.set_xlabel("s1")
    ax.set_ylabel("s2" if model.latent_dim > 1 else "")
    ax.set_title("Object manifold (stars: S; dots: one training touch's belief)", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    return _save(fig, path)


def trajectory_figure(
    reports: dict[str, EvaluationReport], actions: TouchActions, path: Path, touches: int = 5
) -> Path:
    """Joint trajectories of the first ``touches`` actions of the first trial per policy
    (source ``model`` when present, as the paper's Fig. 11), and the teaching trajectory."""
    plt = _pyplot()
    report = reports.get("model") or next(iter(reports.values()))
    firsts: dict[str, Any] = {}
    first_object = report.object_names[0] if report.object_names else None
    for record in report.records:  # O1's first trial per policy, as the paper shows O1
        kept = firsts.get(record.policy)
        if kept is None or (record.target == first_object and kept.target != first_object):
            firsts[record.policy] = record
    teaching = actions.trajectory(np.zeros(actions.action_dim))
    t = np.arange(teaching.shape[0]) * actions.dt_s
    joints = ("FFJ3 (flexion)", "FFJ4 (abduction)")
    fig, axes = plt.subplots(
        len(joints),
        max(len(firsts), 1),
        figsize=(4 * max(len(firsts), 1), 5),
        dpi=110,
        squeeze=False,
    )
    colours = plt.get_cmap("viridis")
    for column, (policy, record) in enumerate(sorted(firsts.items())):
        chosen = record.actions[:touches]
        for row, joint in enumerate(joints):
            ax = axes[row][column]
            ax.plot(t, teaching[:, row], color="black", linestyle="--", label="teaching (x = 0)")
            for k, x in enumerate(chosen):
                trajectory = actions.trajectory(np.asarray(x))
                ax.plot(
                    t,
                    trajectory[:, row],
                    color=colours(k / max(len(chosen) - 1, 1)),
                    label=f"touch {k + 1}",
                )
            ax.set_title(f"{policy}: {joint}, target {record.target}", fontsize=8)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("angle (deg)")
            if row == 0 and column == 0:
                ax.legend(fontsize=6)
    return _save(fig, path)


def accuracy_figure(report: EvaluationReport, source: str, path: Path) -> Path:
    """Accuracy by touch with the 95 % intervals, one curve per policy."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4), dpi=110)
    for policy, figures in report.summary().items():
        accuracy = np.asarray(figures["accuracy_by_touch"])
        interval = np.asarray(figures["accuracy_interval"])
        steps = np.arange(1, accuracy.size + 1)
        ax.plot(steps, 100 * accuracy, marker="o", markersize=3, label=policy)
        ax.fill_between(steps, 100 * interval[:, 0], 100 * interval[:, 1], alpha=0.2)
    ax.set_xlabel("touch")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 102)
    ax.set_title(f"Experiment 2, observations from the {source}", fontsize=9)
    ax.legend(fontsize=8)
    return _save(fig, path)


def reliability_figure(report: EvaluationReport, source: str, path: Path) -> Path:
    """Stated probability against observed accuracy of every answer, one curve per policy."""
    from app.evaluation.plot import draw_reliability

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4.5), dpi=110)
    draw_reliability(ax, report.summary())
    ax.set_title(f"Experiment 2, observations from the {source}: reliability", fontsize=9)
    return _save(fig, path)
