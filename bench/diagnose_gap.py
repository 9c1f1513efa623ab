"""Diagnose the gap between the learned model and the simulated rig on a table.

Why are the learned model's answers confidently wrong on the rig when they are calibrated on the
model's own samples? This bench splits the gap into measurable parts (docs/method.md,
"Calibration and model error"; the figures are in docs/diagnosis.md):

(a) **Held-out predictive fit of fresh rig touches.** For touches the model never saw, at
    *training-like* actions (x ~ N(0, σ² I) with σ the training actions' spread) and at the
    actions the planners chose in rig trials, the per-touch predictive log-density under the
    true object's learned latent and the standardised residuals z = (y' − m) / √v per
    model-space feature (y' the observation in the model's space, m and v the GP predictive
    mean and variance, noise included). The same quantities for draws from the model itself at
    the same actions are the reference: there z ~ N(0, 1) by construction. E[z²] > 1 says the
    model is too sure of a touch (its predictive variance too small or its mean off); a mean z
    away from 0, that it is biased there. The training actions' Mahalanobis distance
    d = √((x − x̄)ᵀ C⁻¹ (x − x̄) / dx) says how far outside the training design an action lies.
(b) **Within-trial residual correlation.** Touches of one trial share one placement of the object
    (and slow drift); the object likelihood treats them as independent. The intra-class
    correlation ρ of z by placement (one-way random-effects ANOVA) measures that share; with n
    touches per trial, the evidence of a trial is then over-counted by the design effect
    1 + (n − 1) ρ. Fresh training-like touches are taken both ways: the object placed once for a
    group of touches and placed anew before every touch.
(c) **Accuracy and calibration on worlds ``model`` and ``rig`` side by side**, per policy, with
    the evaluation engine (:func:`app.evaluation.runner.run_evaluation`, as ``activetouch
    evaluate``) and :mod:`core.evaluation.calibration` over every (trial, touch): accuracy after
    touch 1 and T, expected calibration error, Brier score, log-loss, and the answers given with p ≥
    the confidence threshold that were wrong.

Run: ``python -m bench.diagnose_gap --table cushions [--model M.json | --touches 40
[--action-scale S]] [--trials 10] [--steps 6] [--policies active,discriminative,passive]
[--groups 8] [--group-size 6] [--seed 0] [--json OUT]``. Without ``--model`` it collects and
fits with the documented commands (``activetouch collect --sim --table T --touches N --design
random [--action-scale S] --seed SEED``, ``activetouch fit --latent-dim 2 --seed SEED``) in a
temporary directory. Everything runs in this process on one thread.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from threadpoolctl import threadpool_limits

from app.evaluation.context import TrialContext, TrialKey
from app.evaluation.report import EvaluationReport
from app.evaluation.rig_trial import RigTrial
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec, Placement
from core.errors import TouchRefused
from core.evaluation import (
    ModelSamples,
    RefusedTrial,
    Touch,
    TrialRecord,
    WorldTouches,
    calibration,
)
from core.gp import predict_model_space
from core.gp.noise_model import loo_log_likelihoods
from core.gp.noise_model import standardised_residuals as loo_residuals
from core.types import ManifoldModel
from core.validation import FloatArray
from hardware.sim.materials import TactileObject

# ---------------------------------------------------------------------------------------------
# Pure statistics (tested in tests/bench/test_diagnose_gap.py)
# ---------------------------------------------------------------------------------------------


def intraclass_correlation(values: npt.ArrayLike, groups: npt.ArrayLike) -> float:
    """One-way random-effects intra-class correlation ICC(1) of ``values`` grouped by ``groups``.

    With g groups, N values, group sizes n_i, MSB = Σ n_i (ȳ_i − ȳ)² / (g − 1) and
    MSW = Σ_i Σ_j (y_ij − ȳ_i)² / (N − g), the between-group variance is estimated as
    σ_b² = (MSB − MSW) / n0 with n0 = (N − Σ n_i² / N) / (g − 1), and
    ICC = σ_b² / (σ_b² + MSW) (Shrout & Fleiss 1979, ICC(1); unbalanced groups by n0). It can be
    negative when groups vary less than chance would make them.

    Args:
        values: One value per observation. Shape (N,).
        groups: Group label of each observation. Shape (N,).

    Returns:
        The ICC; ``nan`` with fewer than two groups or no within-group replicate.
    """
    y = np.asarray(values, dtype=np.float64)
    g = np.asarray(groups)
    if y.ndim != 1 or g.shape != y.shape:
        raise ValueError(f"values and groups: expected two arrays (N,), got {y.shape}, {g.shape}")
    labels, index = np.unique(g, return_inverse=True)
    n_groups, n = labels.size, y.size
    if n_groups < 2 or n <= n_groups:
        return float("nan")
    sizes = np.bincount(index).astype(np.float64)
    means = np.bincount(index, weights=y) / sizes
    grand = y.mean()
    msb = float(np.sum(sizes * (means - grand) ** 2) / (n_groups - 1))
    msw = float(np.sum((y - means[index]) ** 2) / (n - n_groups))
    n0 = (n - np.sum(sizes**2) / n) / (n_groups - 1)
    between = (msb - msw) / n0
    total = between + msw
    return float(between / total) if total > 0 else float("nan")


def design_effect(icc: float, touches: int) -> float:
    """1 + (n − 1) ρ: how many times a trial's evidence is over-counted by treating its n
    touches as independent when they share a random effect with intra-class correlation ρ."""
    return 1.0 + (touches - 1) * icc


def action_distance(actions: FloatArray, training_actions: FloatArray) -> FloatArray:
    """√((x − x̄)ᵀ C⁻¹ (x − x̄) / dx) of each action from the training actions (mean x̄,
    covariance C): about 1 inside a Gaussian training design, larger outside it.

    Args:
        actions: Shape (n, dx).
        training_actions: Shape (N, dx), N > dx.

    Returns:
        Shape (n,).
    """
    x = np.asarray(actions, dtype=np.float64)
    train = np.asarray(training_actions, dtype=np.float64)
    centre = train.mean(axis=0)
    precision = np.linalg.inv(np.atleast_2d(np.cov(train, rowvar=False)))
    d = x - centre
    return np.asarray(np.sqrt(np.einsum("ni,ij,nj->n", d, precision, d) / x.shape[1]))


@dataclass(frozen=True)
class ResidualSummary:
    """Residual statistics of a set of touches (each under its true object).

    Attributes:
        touches: Number of touches.
        log_density: Mean predictive log-density per touch (raw units, nats).
        mean_z: Mean standardised residual per model-space feature. Shape (dy,).
        mean_z2: Mean z² per feature (1 when calibrated). Shape (dy,).
        tail_share: Share of |z| > 3 over every (touch, feature) (0.0027 when calibrated).
        icc: Intra-class correlation of z by placement, per feature (``nan`` without groups).
        epistemic_share: Mean share of the predictive variance that is the GP's own
            (v − σ_n²) / v, over touches and features: how unsure the model says it is.
        distance: Mean :func:`action_distance` of the touches' actions.
    """

    touches: int
    log_density: float
    mean_z: FloatArray
    mean_z2: FloatArray
    tail_share: float
    icc: FloatArray
    epistemic_share: float
    distance: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "touches": self.touches,
            "log_density": self.log_density,
            "mean_z": self.mean_z.tolist(),
            "mean_z2": self.mean_z2.tolist(),
            "tail_share": self.tail_share,
            "icc": [None if not np.isfinite(v) else float(v) for v in self.icc],
            "epistemic_share": self.epistemic_share,
            "distance": self.distance,
        }


def standardised_residuals(
    model: ManifoldModel, object_index: npt.ArrayLike, actions: FloatArray, raw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """z = (y' − m) / √v of every touch under its object's learned latent.

    Returns:
        ``(z, log_density, epistemic_share)``: z shape (n, dy); the per-touch log-density
        Σ_a log N(y'_a; m_a, v_a) + log|det M| (as :func:`core.recognition.object_posterior
        .touch_log_likelihoods`), shape (n,); (v − σ_n²) / v, shape (n, dy).
    """
    index = np.asarray(object_index, dtype=np.int64)
    mean, variance = predict_model_space(model, model.latents[index], actions)
    residual = model.to_model_space(raw) - mean
    z = residual / np.sqrt(variance)
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    log_density = -0.5 * np.sum(np.log(2.0 * np.pi * variance) + z**2, axis=1) + jacobian
    noise = model.hyperparameters.noise_variance[None, :]
    return z, log_density, (variance - noise) / variance


def summarise(
    model: ManifoldModel,
    object_index: npt.ArrayLike,
    actions: FloatArray,
    raw: FloatArray,
    groups: npt.ArrayLike | None,
) -> ResidualSummary:
    """:class:`ResidualSummary` of touches (object, action, raw y), grouped by placement."""
    z, log_density, epistemic = standardised_residuals(model, object_index, actions, raw)
    dy = z.shape[1]
    icc = (
        np.full(dy, np.nan)
        if groups is None
        else np.array([intraclass_correlation(z[:, a], groups) for a in range(dy)])
    )
    return ResidualSummary(
        touches=int(z.shape[0]),
        log_density=float(log_density.mean()),
        mean_z=z.mean(axis=0),
        mean_z2=(z**2).mean(axis=0),
        tail_share=float(np.mean(np.abs(z) > 3.0)),
        icc=icc,
        epistemic_share=float(epistemic.mean()),
        distance=float(action_distance(actions, model.raw_data.actions).mean()),
    )


# ---------------------------------------------------------------------------------------------
# Touch sequences: on the rig and from the model
# ---------------------------------------------------------------------------------------------


@dataclass
class Touches:
    """Touches of several sequences: object index, action, raw observation, sequence id."""

    objects: list[int]
    actions: list[FloatArray]
    observations: list[FloatArray]
    groups: list[int]

    @classmethod
    def empty(cls) -> Touches:
        """No touches yet."""
        return cls([], [], [], [])

    def add(self, obj: int, action: FloatArray, y: FloatArray, group: int) -> None:
        """One touch of object ``obj`` at ``action`` (dx,) observing raw ``y`` (dy,)."""
        self.objects.append(obj)
        self.actions.append(np.asarray(action, dtype=np.float64))
        self.observations.append(np.asarray(y, dtype=np.float64))
        self.groups.append(group)

    def summary(self, model: ManifoldModel) -> ResidualSummary:
        """:func:`summarise` of these touches, grouped by sequence."""
        return summarise(
            model,
            np.array(self.objects),
            np.array(self.actions),
            np.array(self.observations),
            np.array(self.groups),
        )


@dataclass(frozen=True)
class TouchSequence:
    """Actions touched one after another on one object (one trial's or one placement's)."""

    target: str
    actions: FloatArray  # (n, dx)
    seed: int


def touch_sequences(
    model: ManifoldModel,
    table_objects: tuple[str | TactileObject, ...],
    sequences: Sequence[TouchSequence],
    *,
    placement: Placement,
) -> tuple[Touches, Touches, int]:
    """Touch each sequence on a fresh simulated rig and draw it from the model.

    Returns:
        ``(rig, model, refused)``: the rig's touches and the model's draws at the same actions
        (each sequence one group), and the number of sequences the rig refused a touch of
        (their touches before the refusal are kept).
    """
    from app.rig.actions import TouchActions

    touch_actions = TouchActions.from_teaching()
    rig_touches, model_touches, refused = Touches.empty(), Touches.empty(), 0
    for g, seq in enumerate(sequences):
        obj = model.object_names.index(seq.target)
        rig = RigTrial(
            touch_actions,
            table_objects,
            seq.target,
            seq.seed,
            placement=placement,
            features=model.features,
        )
        draw = WorldTouches(ModelSamples(model), seq.target)
        rng = np.random.default_rng(seq.seed)
        try:
            for action in seq.actions:
                rig_touches.add(obj, action, rig.touch(action, rng).observation, g)
                model_touches.add(obj, action, draw.touch(action, rng).observation, g)
        except TouchRefused:
            refused += 1
        finally:
            rig.close()
    return rig_touches, model_touches, refused


def training_like_sequences(
    model: ManifoldModel, groups: int, group_size: int, seed: int
) -> list[TouchSequence]:
    """``groups`` sequences of ``group_size`` actions x ~ N(x̄, diag(s²)) with x̄, s the training
    actions' mean and spread per dimension, targets in turn over the model's objects."""
    train = model.raw_data.actions
    centre, spread = train.mean(axis=0), train.std(axis=0)
    rng = np.random.default_rng(seed)
    names = model.object_names
    return [
        TouchSequence(
            names[g % len(names)],
            centre + spread * rng.standard_normal((group_size, train.shape[1])),
            int(rng.integers(2**31)),
        )
        for g in range(groups)
    ]


class CapturingContext(TrialContext):
    """The engine's trial context, keeping every rig observation of its trials.

    :attr:`captured` maps a trial key (policy, target, index) to its touches' actions and raw
    observations, so the residuals at the planners' actions come from the very touches the
    trials saw (no second rig run).
    """

    def __init__(self, model: ManifoldModel, spec: EvaluationSpec) -> None:
        super().__init__(model, spec)
        self.captured: dict[TrialKey, list[tuple[FloatArray, FloatArray]]] = {}

    def open_rig_trial(self, key: TrialKey, seed: int) -> RigTrial:
        rig = super().open_rig_trial(key, seed)
        touches = self.captured.setdefault(key, [])
        touch = rig.touch

        def captured(action: FloatArray, rng: np.random.Generator) -> Touch:
            done = touch(action, rng)
            touches.append((np.array(action, dtype=np.float64), done.observation))
            return done

        rig.touch = captured  # type: ignore[method-assign]
        return rig


def evaluate(
    model: ManifoldModel, spec: EvaluationSpec
) -> tuple[EvaluationReport, dict[TrialKey, list[tuple[FloatArray, FloatArray]]]]:
    """The evaluation of ``spec``: :func:`app.evaluation.runner.run_evaluation` for a sampled
    world; for the rig, the same trials (the engine's :class:`TrialContext`, in order, one
    thread) with their observations captured."""
    if spec.world != "rig":
        return run_evaluation(model, spec), {}
    spec.check(model)
    started = time.perf_counter()
    context = CapturingContext(model, spec)
    outcomes = context.run_many(context.trial_keys())
    report = EvaluationReport(
        spec=spec,
        records=tuple(r for r in outcomes if isinstance(r, TrialRecord)),
        refused=tuple(r for r in outcomes if isinstance(r, RefusedTrial)),
        seconds=time.perf_counter() - started,
        workers=1,
        stopped=False,
        object_names=model.object_names,
        steps=context.steps,
    )
    return report, context.captured


def planner_touches(
    model: ManifoldModel,
    captured: dict[TrialKey, list[tuple[FloatArray, FloatArray]]],
    policy: str,
    seed: int,
) -> tuple[Touches, Touches]:
    """The rig touches of ``policy``'s trials (each trial one group) and the model's own draws
    at the same actions."""
    rig_t, model_t = Touches.empty(), Touches.empty()
    keys = [k for k in captured if k[0] == policy]
    for g, key in enumerate(keys):
        obj = model.object_names.index(key[1])
        draw = WorldTouches(ModelSamples(model), key[1])
        rng = np.random.default_rng([seed, g])
        for action, y in captured[key]:
            rig_t.add(obj, action, y, g)
            model_t.add(obj, action, draw.touch(action, rng).observation, g)
    return rig_t, model_t


def training_loo(model: ManifoldModel) -> dict[str, Any] | None:
    """Leave-one-out fit of the training touches themselves (at the fitted latents and
    hyperparameters, so optimistic): mean log-density per touch and E[z²] per feature.
    ``None`` for a sparse posterior."""
    log_density = loo_log_likelihoods(model)
    if log_density is None:
        return None
    z = loo_residuals(model)
    return {
        "touches": int(z.shape[0]),
        "log_density": float(log_density.mean()),
        "mean_z2": (z**2).mean(axis=0).tolist(),
        "tail_share": float(np.mean(np.abs(z) > 3.0)),
    }


# ---------------------------------------------------------------------------------------------
# Accuracy and calibration of an evaluation
# ---------------------------------------------------------------------------------------------


def evaluation_figures(report: EvaluationReport, policy: str, threshold: float) -> dict[str, Any]:
    """Accuracy after each touch (answer carried forward after an early stop) and the
    calibration of every (trial, touch) answer actually given, for one policy."""
    names = report.object_names
    records = [r for r in report.records if r.policy == policy]
    steps = report.steps
    right = np.zeros(steps)
    probabilities: list[tuple[float, ...]] = []
    labels: list[int] = []
    for r in records:
        truth = names.index(r.target)
        for t in range(steps):
            answer = r.answers[min(t, r.touches - 1)]
            right[t] += answer == r.target
        probabilities.extend(r.probabilities)
        labels.extend([truth] * r.touches)
    p = np.array(probabilities, dtype=np.float64)
    p /= p.sum(axis=1, keepdims=True)
    c = calibration(p, np.array(labels, dtype=np.int64), threshold)
    return {
        "trials": len(records),
        "accuracy_by_touch": (right / max(len(records), 1)).tolist(),
        "ece": c.ece,
        "brier": c.brier,
        "log_loss": c.log_loss,
        "sure": c.sure_and_wrong.sure,
        "sure_wrong": c.sure_and_wrong.wrong,
    }


# ---------------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------------


def fitted_model(args: argparse.Namespace, workdir: Path) -> ManifoldModel:
    """The model of ``--model``, or one collected and fitted with the documented commands."""
    from app.cli.main import load_model

    if args.model is not None:
        return load_model(args.model)
    exe = [str(Path(sys.executable).parent / "activetouch")]
    csv, model = workdir / "train.csv", workdir / "model.json"
    collect = [
        *exe,
        "collect",
        "--sim",
        "--table",
        args.table,
        "--touches",
        str(args.touches),
        "--design",
        "random",
        "--seed",
        str(args.seed),
        "--out",
        str(csv),
    ]
    if args.action_scale is not None:
        collect += ["--action-scale", str(args.action_scale)]
    seed = str(args.seed)
    fit = [*exe, "fit", str(csv), "--latent-dim", "2", "--seed", seed, "--out", str(model)]
    for command in (collect, fit):
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return load_model(model)


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Every figure of the diagnosis, as a JSON-ready dict."""
    from app.evaluation.context import rig_table

    started = time.perf_counter()
    table = rig_table(args.table)
    table_objects = table.slots
    policies = tuple(args.policies.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        model = fitted_model(args, Path(tmp))
    missing = [n for n in model.object_names if n not in table.objects]
    if missing:
        raise SystemExit(f"--model: objects {missing} are not on the table {args.table!r}.")
    out: dict[str, Any] = {
        "table": args.table,
        "model": str(args.model) if args.model else f"collect {args.touches}/object, fit ds=2",
        "training_action_std": model.raw_data.actions.std(axis=0).tolist(),
        "noise_model": "identity" if model.transform is None else "transformed",
        "seconds": {},
    }
    # (c) worlds model and rig, per policy.
    reports: dict[str, EvaluationReport] = {}
    captured: dict[TrialKey, list[tuple[FloatArray, FloatArray]]] = {}
    for world in ("model", "rig"):
        t0 = time.perf_counter()
        spec = EvaluationSpec(
            world=world,
            trials_per_target=args.trials,
            steps=args.steps,
            policies=policies,
            seed=args.seed,
            table=args.table if world == "rig" else None,
            confidence=args.confidence,
        )
        reports[world], found = evaluate(model, spec)
        captured.update(found)
        out["seconds"][f"evaluate_{world}"] = time.perf_counter() - t0
    out["evaluation"] = {
        world: {p: evaluation_figures(rep, p, args.confidence) for p in policies}
        for world, rep in reports.items()
    }
    # (a), (b): fresh touches at training-like actions (placed once / anew) and planner actions.
    residuals: dict[str, dict[str, Any]] = {}
    t0 = time.perf_counter()
    train_like = training_like_sequences(model, args.groups, args.group_size, args.seed + 1)
    modes: tuple[tuple[str, Placement], ...] = (
        ("training-like, placed once", "trial"),
        ("training-like, placed anew", "touch"),
    )
    for label, placement in modes:
        rig_t, model_t, refused = touch_sequences(
            model, table_objects, train_like, placement=placement
        )
        residuals[label] = {
            "rig": rig_t.summary(model).to_dict(),
            "model": model_t.summary(model).to_dict(),
            "refused_sequences": refused,
        }
    for policy in policies:
        rig_t, model_t = planner_touches(model, captured, policy, args.seed)
        residuals[f"{policy}'s rig-trial actions"] = {
            "rig": rig_t.summary(model).to_dict(),
            "model": model_t.summary(model).to_dict(),
            "refused_sequences": len([r for r in reports["rig"].refused if r.policy == policy]),
        }
    out["seconds"]["residuals"] = time.perf_counter() - t0
    out["training_loo"] = training_loo(model)
    out["residuals"] = residuals
    out["seconds"]["total"] = time.perf_counter() - started
    return out


def _fmt(values: Sequence[float | None], spec: str = "{:.2f}") -> str:
    return " ".join("—" if v is None or not np.isfinite(v) else spec.format(v) for v in values)


def print_report(out: dict[str, Any]) -> None:
    """The compact tables."""
    print(f"table {out['table']}; model: {out['model']}; noise model {out['noise_model']}")
    print("training action std per dim:", _fmt(out["training_action_std"]))
    print("\n(c) accuracy touch 1 -> T, calibration over every (trial, touch)")
    print(
        f"{'world':6} {'policy':15} {'n':>4} {'acc 1->T':>10} {'ECE':>5} {'Brier':>5} "
        f"{'logloss':>7} {'sure&wrong':>12}"
    )
    for world, per_policy in out["evaluation"].items():
        for policy, f in per_policy.items():
            acc = f["accuracy_by_touch"]
            sw = f"{f['sure_wrong']}/{f['sure']}"
            share = f" {100 * f['sure_wrong'] / f['sure']:.0f}%" if f["sure"] else ""
            print(
                f"{world:6} {policy:15} {f['trials']:>4} "
                f"{100 * acc[0]:>4.0f}->{100 * acc[-1]:<4.0f}"
                f" {f['ece']:>5.2f} {f['brier']:>5.2f} {f['log_loss']:>7.2f} {sw + share:>12}"
            )
    print("\n(a, b) fresh touches under the true object's latent: rig vs the model's own draws")
    print(
        f"{'actions':34} {'src':5} {'n':>4} {'dist':>5} {'logp':>7} {'E[z2] per feature':>26} "
        f"{'|z|>3':>6} {'ICC per feature':>26} {'epi':>5}"
    )
    for label, r in out["residuals"].items():
        for src in ("rig", "model"):
            s = r[src]
            print(
                f"{label:34} {src:5} {s['touches']:>4} {s['distance']:>5.2f} "
                f"{s['log_density']:>7.2f} {_fmt(s['mean_z2']):>26} {s['tail_share']:>6.3f} "
                f"{_fmt(s['icc']):>26} {s['epistemic_share']:>5.2f}"
            )
        if r["refused_sequences"]:
            print(f"{'':34} ({r['refused_sequences']} sequences refused by the rig)")
    loo = out["training_loo"]
    if loo is not None:
        print(
            f"{'training touches, leave-one-out':34} {'loo':5} {loo['touches']:>4} {'':>5} "
            f"{loo['log_density']:>7.2f} {_fmt(loo['mean_z2']):>26} {loo['tail_share']:>6.3f}"
        )
    print("\nmean z per feature (rig):")
    for label, r in out["residuals"].items():
        print(f"  {label:34} {_fmt(r['rig']['mean_z'])}")
    print("\nseconds:", {k: round(v, 1) for k, v in out["seconds"].items()})


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--table", required=True, help="Simulated table (rig status --sim).")
    parser.add_argument("--model", type=Path, help="Model document; else collect and fit.")
    parser.add_argument("--touches", type=int, default=40, help="Touches per object to collect.")
    parser.add_argument("--action-scale", type=float, help="collect --action-scale (default: its).")
    parser.add_argument("--trials", type=int, default=10, help="Trials per target and policy.")
    parser.add_argument("--steps", type=int, default=6, help="T.")
    parser.add_argument("--policies", default="active,discriminative,passive")
    parser.add_argument("--confidence", type=float, default=0.95)
    parser.add_argument("--groups", type=int, default=8, help="Training-like sequences.")
    parser.add_argument("--group-size", type=int, default=6, help="Touches per sequence.")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="Also write every figure here.")
    args = parser.parse_args(argv)
    with threadpool_limits(limits=1):
        out = run(args)
    print_report(out)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
