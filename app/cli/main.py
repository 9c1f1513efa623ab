"""The ``activetouch`` command line: fit, recognize, collect, export, the rig, the server.

Progress bars go to stderr; with ``--json`` stdout carries only the JSON document.

Starting the CLI imports only typer and rich: every command imports what it needs (numpy and
the core, the drivers, the web stack) when it runs, so ``activetouch --help`` or ``activetouch
fit`` do not pay for FastAPI, SQLAlchemy or viser. ``serve``, ``demo`` and ``bench`` live in
modules that import their stack at the top; they are registered here as thin commands that
import the module and hand it their arguments (:func:`_forward`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import json
import os
import sys
import time
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer
from rich.markup import escape

from app.cli.collect import collect_command
from app.cli.dataset import dataset_app
from app.cli.evaluate import evaluate_command
from app.cli.export import export_app
from app.cli.output import fail, progress_bar, read_text, write_text
from app.cli.output import messages as stderr
from app.cli.output import results as stdout
from app.cli.paper import paper_app
from app.cli.raw_data import FeaturesName, features_summary
from app.cli.rig import rig_app

if TYPE_CHECKING:
    from app.services.fit_tasks import FitEngine
    from core.evaluation import World
    from core.gp import FitOptions, NoiseModelChoice, StartMap
    from core.selection import LatentSelection
    from core.types import ManifoldModel, TrainingData

app = typer.Typer(
    name="activetouch",
    help="Active tactile object recognition: learn an object manifold, recognise by touch.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)


class Optimizer(StrEnum):
    """Optimisers of the manifold fit."""

    lbfgs = "lbfgs"
    de = "de"


class PoolingChoice(StrEnum):
    """How a fit pools the objects' placements into one placement variance
    (:data:`core.gp.placement_effect.PLACEMENT_POOLINGS`, listed here so that ``--help`` does not
    load the numerics)."""

    mean = "mean"
    median = "median"


class ShiftAlong(StrEnum):
    """Which action dimensions a fit lets a placement shift
    (:data:`app.rig.action_layout.SHIFT_ALONG`)."""

    auto = "auto"
    all = "all"


class WorldName(StrEnum):
    """Simulated worlds a trial or a dataset can come from
    (:data:`core.evaluation.worlds.WORLD_NAMES`, listed here so that ``--help`` does not load the
    numerics)."""

    exp1 = "exp1"
    exp2 = "exp2"


class Policy(StrEnum):
    """Action policies of a recognition trial (:data:`core.recognition.planning.POLICY_NAMES`,
    listed here so that ``--help`` does not load the numerics)."""

    active = "active"
    discriminative = "discriminative"
    passive = "passive"
    fixed = "fixed"


def fit_with_progress(
    data: TrainingData,
    latent_dim: int,
    options: FitOptions,
    seed: int,
    quiet: bool = False,
    noise_model: NoiseModelChoice | None = None,
    start_map: StartMap | None = None,
    fitted: ManifoldModel | None = None,
) -> tuple[ManifoldModel, float]:
    """Run :func:`core.gp.manifold.iter_fit` with a progress bar; return the model and seconds.

    With ``start_map`` (e.g. :meth:`app.services.fit_tasks.FitEngine.start_map`) the starts'
    first stage runs there, with the same model. ``fitted``: the fit at this ds already done
    by the selection of ds (:attr:`core.selection.LatentSelection.chosen_model`); only the
    noise model's refit then runs."""
    import numpy as np

    from app.services.remaining import RemainingTime
    from core.gp import iter_fit

    rng = np.random.default_rng(seed)
    started = time.perf_counter()
    model: ManifoldModel | None = None
    remaining = RemainingTime()
    with progress_bar(disable=quiet) as bar:
        task = bar.add_task("fit", total=1.0, status="")
        for event in iter_fit(data, latent_dim, rng, options, noise_model, start_map, fitted):
            # The bar fills with the share of the fit's stages done (event.fraction) and the
            # time left is estimated from it; the status says which stage runs.
            best = event.best_log_likelihood
            left = remaining.update("fit", event.fraction, time.perf_counter() - started)
            bar.update(
                task,
                completed=event.fraction,
                ends_at=None if left is None else time.monotonic() + left,
                status=f"{escape(event.phase)}: start {event.start + 1:d}/{event.n_starts:d}, "
                f"iteration {event.iteration:d}"
                + (f", best log-lik {best:.2f}" if np.isfinite(best) else ""),
            )
            if event.model is not None:
                model = event.model
        bar.update(task, total=1, completed=1, status="done")
    if model is None:
        raise fail("the fit ended without a model")
    return model, time.perf_counter() - started


def select_latent_dim_with_progress(
    data: TrainingData,
    options: FitOptions,
    seed: int,
    noise_model: NoiseModelChoice,
    workers: int | None = None,
    scheduler: str | None = None,
    engine: FitEngine | None = None,
) -> LatentSelection:
    """Cross-validate ds (:func:`core.selection.latent_selection.select_latent_dim`, warm folds:
    every candidate fitted on all the touches, each fold refitted from it) with a progress bar.

    The fits use the requested noise model ("independent" for "auto", which the final fit
    decides from the chosen candidate's fit). With ``workers`` or ``scheduler`` they run as
    Dask tasks (:mod:`app.services.fit_tasks`; on ``engine`` when given), with the same
    result; the bar then advances as each fit and fold finishes.

    Raises:
        BadInputError: The scheduler cannot be reached or has no worker.
    """

    import numpy as np

    from app.services.fit_tasks import FitEngine, FoldFit
    from app.services.remaining import RemainingTime
    from core.selection import (
        DEFAULT_FOLDS,
        RUNG_COST_IN_REFITS,
        candidate_dims,
        select_latent_dim,
        serial_map,
        serial_warm_map,
    )

    fewest = int(data.touches_per_object().min())
    if fewest < 4:
        raise fail(
            f"--latent-dim auto cross-validates over touches within objects and needs at least "
            f"4 touches of every object; an object here has {fewest:d}."
        )
    n_folds = min(DEFAULT_FOLDS, fewest - 2)
    n_candidates = len(candidate_dims(data.n_objects))
    # Progress in units of one fold's refit; a fit on all the touches counts as many.
    total = n_candidates * (RUNG_COST_IN_REFITS + n_folds)
    rng = np.random.default_rng(seed)
    fold_noise: NoiseModelChoice = "independent" if noise_model == "auto" else noise_model
    fold_fit = FoldFit(options, fold_noise)
    started = time.perf_counter()
    remaining = RemainingTime()
    done = [0]
    with progress_bar() as bar, contextlib.ExitStack() as stack:
        task = bar.add_task("latent dim", total=total, status="")

        def advance(units: int, status: str) -> None:
            done[0] += units
            elapsed_s = time.perf_counter() - started
            left = remaining.update("latent selection", done[0] / total, elapsed_s)
            bar.update(
                task,
                advance=units,
                ends_at=None if left is None else time.monotonic() + left,
                status=status,
            )

        def on_rung(ds: int, log_likelihood: float) -> None:
            status = f"ds={ds:d} on all the touches: log-lik {log_likelihood:.2f}"
            advance(RUNG_COST_IN_REFITS, status)

        def on_fold(ds: int, fold: int, score: float) -> None:
            advance(1, f"ds={ds:d}, fold {fold + 1:d}/{n_folds:d}: {score:.3f} nats/touch")

        if engine is None and (workers is not None or scheduler is not None):
            engine = stack.enter_context(FitEngine(workers, scheduler))
        return select_latent_dim(
            data,
            fold_fit,
            rng,
            n_folds=n_folds,
            callback=on_fold,
            map=serial_map if engine is None else engine.fold_map,
            refit=fold_fit.refit,
            warm_map=serial_warm_map if engine is None else engine.warm_map,
            rung_callback=on_rung,
        )


def _parse_latent_dim(value: str) -> int | None:
    """``--latent-dim``: an integer ≥ 1, or ``auto`` (→ ``None``)."""
    if value.strip().lower() == "auto":
        return None
    try:
        number = int(value)
    except ValueError:
        raise typer.BadParameter(f"expected an integer ≥ 1 or 'auto', got {value!r}") from None
    if number < 1:
        raise typer.BadParameter(f"expected an integer ≥ 1 or 'auto', got {number:d}")
    return number


@app.command()
def fit(
    data_csv: Annotated[
        Path,
        typer.Argument(
            help="Training CSV (object,x_1..x_dx,y_1..y_dy) or raw-touch file (JSON lines, "
            "docs/raw-touches.md)."
        ),
    ],
    latent_dim: Annotated[
        str,
        typer.Option(
            "--latent-dim",
            help="ds, or 'auto': choose it by cross-validated held-out likelihood "
            "(candidates 1..min(5, L-1)). Default 2 (what the adaptive collection design's "
            "fits use).",
        ),
    ] = "2",
    noise_model: Annotated[
        Literal["auto", "independent", "correlated"],
        typer.Option(
            "--noise-model",
            help="independent: standardise each feature; correlated: also whiten the noise "
            "correlation across features from a first fit's residuals, then refit; auto: both, "
            "keep correlated if it wins on leave-one-out likelihood.",
        ),
    ] = "auto",
    optimizer: Annotated[Optimizer, typer.Option(help="lbfgs or de")] = Optimizer.lbfgs,
    restarts: Annotated[int, typer.Option(min=0, help="Random restarts after the PCA start.")] = 4,
    kernels: Annotated[
        Literal["per_feature", "tied"],
        typer.Option(
            help="per_feature: every feature its own length-scales. tied: the features share "
            "them (each keeps its variances), one eigendecomposition per evaluation for all: "
            "much faster from about 5 features on (docs/fitting.md, 'Tied kernels'). Dense "
            "structure only."
        ),
    ] = "per_feature",
    seed: Annotated[int, typer.Option(help="Seed of the random restarts.")] = 0,
    structure: Annotated[
        Literal["auto", "dense", "kronecker", "sparse"],
        typer.Option(
            help="GP structure: auto = kronecker for a shared action design, dense up to 3000 "
            "touches, sparse above."
        ),
    ] = "auto",
    inducing: Annotated[
        int, typer.Option(min=1, help="Inducing points of the sparse structure.")
    ] = 512,
    features: Annotated[
        FeaturesName | None,
        typer.Option(
            help="How y is made of a raw touch: means (each channel's mean, as the paper) or "
            "whole (reducers of every series, standardised, PCA to dy). Default: whole for raw "
            "touches; a training CSV already holds y."
        ),
    ] = None,
    feature_dim: Annotated[
        str,
        typer.Option(
            "--feature-dim",
            help="dy of --features whole, or 'auto': by cross-validated recognition.",
        ),
    ] = "auto",
    workers: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Run the starts of the fit (and the folds of --latent-dim auto) on a "
            "LocalCluster of K processes.",
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Threads one likelihood evaluation of this process runs its features on "
            "(the same model on any number). Default: the cores this process may use.",
        ),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            help="Run the starts of the fit (and the folds of --latent-dim auto) on a Dask "
            "scheduler, tcp://host:8786."
        ),
    ] = None,
    latent_uncertainty: Annotated[
        bool,
        typer.Option(
            "--latent-uncertainty/--no-latent-uncertainty",
            help="Carry each object's latent covariance (Laplace) into the object likelihood "
            "(docs/method.md (L1)-(L3)). On by default: it calibrates the cushions' passive "
            "trials on the rig (docs/calibration.md).",
        ),
    ] = True,
    object_placement: Annotated[
        bool,
        typer.Option(
            "--object-placement/--no-object-placement",
            help="When the touches record placements: score each object's trials with its own "
            "placement variance, shrunk towards the pooled one. Off by default: measured, it "
            "cost accuracy (docs/calibration.md, 'Each object's placement variance').",
        ),
    ] = False,
    placement_pooling: Annotated[
        PoolingChoice,
        typer.Option(
            help="When the touches record placements: the placement variance every trial is "
            "scored with is the mean over all placements, or the median over the objects of "
            "each one's own estimate (measured, not adopted: docs/calibration.md, 'The typical "
            "object's placement variance').",
        ),
    ] = PoolingChoice.mean,
    shift_along: Annotated[
        ShiftAlong,
        typer.Option(
            help="When the touches record placements: the action dimensions the input shift is "
            "estimated along. auto: the press depth alone when the actions are the rig's with "
            "it (dx = 7), every dimension otherwise; all: every dimension (docs/calibration.md, "
            "'The shift along the press depth only').",
        ),
    ] = ShiftAlong.auto,
    tempering: Annotated[
        bool,
        typer.Option(
            "--tempering",
            help="A last resort: fit an exponent β ≤ 1 on the object likelihood by "
            "cross-validation on the training touches (docs/calibration.md, 'Fix 6').",
        ),
    ] = False,
    out: Annotated[Path | None, typer.Option(help="Write the model document here.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the model document.")] = False,
) -> None:
    """Learn the object manifold from a training CSV or raw touches."""
    import numpy as np

    from app.cli.raw_data import training_touches
    from app.config import available_cores
    from app.documents.model import latent_selection_dict, model_to_document
    from app.rig.action_layout import shift_dimensions
    from core.errors import CoreError
    from core.gp import FitOptions
    from core.recognition import calibrate

    requested_dim = _parse_latent_dim(latent_dim)
    if workers is not None and scheduler is not None:
        raise fail("--workers and --scheduler: give one (a local cluster or an existing one)")
    refusals: tuple[type[Exception], ...] = (CoreError,)
    if workers is not None or scheduler is not None:
        from app.errors import AppError  # the cluster's refusals; the web stack only then

        refusals = (CoreError, AppError)
    try:
        dy = _parse_latent_dim(feature_dim)
    except typer.BadParameter as exc:
        raise fail(f"--feature-dim: {exc}") from None
    data, pipeline = training_touches(data_csv, features, dy, seed)
    selection = None
    try:
        options = FitOptions(
            optimizer=optimizer.value,
            restarts=restarts,
            kernels=kernels,
            structure=structure,
            n_inducing=inducing,
            threads=available_cores() if threads is None else threads,
        )
        with contextlib.ExitStack() as stack:
            engine = None
            if workers is not None or scheduler is not None:
                from app.services.fit_tasks import FitEngine

                engine = stack.enter_context(FitEngine(workers, scheduler))
            if requested_dim is None:
                selection = select_latent_dim_with_progress(
                    data, options, seed, noise_model, workers, scheduler, engine
                )
                requested_dim = selection.chosen
            model, seconds = fit_with_progress(
                data,
                requested_dim,
                options,
                seed,
                quiet=False,
                noise_model=noise_model,
                start_map=None if engine is None else engine.start_map,
                fitted=None if selection is None else selection.chosen_model,
            )
        model, found = calibrate(
            model,
            options,
            np.random.default_rng(seed),
            latent_uncertainty=latent_uncertainty,
            tempering=tempering,
            object_placement=object_placement,
            placement_pooling=placement_pooling.value,
            shift_dimensions=shift_dimensions(data.action_dim, shift_along.value),
        )
    except refusals as exc:
        raise fail(str(exc)) from None
    if pipeline is not None:
        model = dataclasses.replace(model, features=pipeline)
    document = model_to_document(
        model,
        fit_seconds=seconds,
        latent_selection=None if selection is None else latent_selection_dict(selection),
    )
    if out is not None:
        write_text(out, json.dumps(document, indent=1), "--out")
    if as_json:
        sys.stdout.write(json.dumps(document) + "\n")
        return
    if selection is not None:
        stdout.print("latent dimension by cross-validation (held-out log-likelihood per touch):")
        for c in selection.candidates:
            mark = " <- chosen" if c.latent_dim == selection.chosen else ""
            stdout.print(
                f"  ds={c.latent_dim:d}  {c.mean:.3f} ± {c.standard_error:.3f}  "
                f"vs best {c.difference:+.3f} ± {c.difference_standard_error:.3f}{escape(mark)}"
            )
        stdout.print(escape(selection.explanation))
    if pipeline is not None:
        stdout.print(escape(features_summary(pipeline)))
    noise_note = model.transform.note if model.transform is not None else "none"
    stdout.print(f"noise model: {escape(noise_note)}")
    placement, drift, shift = found.placement, found.drift, found.shift
    laplace, tempering_fit = found.laplace, found.tempering
    if placement is not None:
        noise = model.hyperparameters.noise_variance
        share = placement.variance / noise
        clipped = [
            f"feature {a + 1}: {placement.raw_variance[a] / noise[a]:.3g}"
            for a in np.flatnonzero(placement.raw_variance != placement.variance)
        ]
        stdout.print(
            f"placement effect from {placement.groups:d} placements "
            f"({escape(placement.pooling)} over the objects): σ_b² / σ_n² = "
            f"{escape(np.array2string(share, precision=2))} per feature"
            + (f" (clipped from {escape(', '.join(clipped))})" if clipped else "")
        )
    if found.object_placement is not None:
        by_object = found.object_placement.variance / model.hyperparameters.noise_variance
        stdout.print(
            "each object's own σ_b² / σ_n² (shrunk towards the pooled value): "
            + ", ".join(
                f"{escape(name)} {escape(np.array2string(row, precision=2))}"
                for name, row in zip(model.object_names, by_object, strict=True)
            )
        )
    if drift is not None:
        drift_share = drift.variance / model.hyperparameters.noise_variance
        stdout.print(
            f"drift effect from {drift.pairs:d} pairs of touches within {drift.window_s:.0f} s: "
            f"σ_d² / σ_n² = {escape(np.array2string(drift_share, precision=2))} per feature"
        )
    if shift is not None:
        stdout.print(
            f"input shift from {shift.groups:d} placements: σ_δ = "
            f"{escape(np.array2string(np.sqrt(shift.variance), precision=3))} per action "
            "dimension"
        )
        if shift.runs and np.any(shift.creep > 0.0):
            stdout.print(
                f"its creep from {shift.runs:d} placements of three touches or more: σ_c = "
                f"{escape(np.array2string(np.sqrt(shift.creep), precision=3))} per touch"
            )
        elif shift.runs:
            stdout.print(
                f"no creep of the shift found in {shift.runs:d} placements of three touches or more"
            )
    if laplace is not None:
        spread = np.sqrt(np.trace(laplace.covariance, axis1=1, axis2=2))
        stdout.print(
            f"latent uncertainty (Laplace): RMS std per object "
            f"{escape(np.array2string(spread, precision=3))}"
            + (
                f", {sum(laplace.floored):d} flat direction(s) capped"
                if any(laplace.floored)
                else ""
            )
        )
    for note in found.notes:
        stdout.print(escape(note))
    if tempering_fit is not None:
        stdout.print(
            f"tempering β = {tempering_fit.exponent:.3f} (held-out log-loss "
            f"{tempering_fit.log_loss:.3f} vs {tempering_fit.log_loss_untempered:.3f} nats "
            f"untempered, {tempering_fit.answers:d} answers)"
        )
    stdout.print(
        f"fitted {len(model.object_names):d} objects, ds={model.latent_dim:d}, "
        f"log-likelihood {model.log_likelihood:.3f} in {seconds:.2f} s"
        + (f"; written to {escape(str(out))}" if out else "")
    )
    for name, latent in zip(model.object_names, model.latents, strict=True):
        stdout.print(
            f"  {escape(f'{name:>12s}')}  s = {escape(np.array2string(latent, precision=4))}"
        )


def load_model(path: Path) -> ManifoldModel:
    """Read a model document from a file, with errors that say what is wrong."""
    from app.documents.model import model_from_document
    from core.errors import CoreError

    text = read_text(path)
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise fail(f"{path} is not JSON: {exc}") from None
    except RecursionError:
        raise fail(f"{path} is not a model document: it is nested too deeply") from None
    except ValueError as exc:  # an integer over Python's digit limit
        raise fail(f"{path} is not JSON this program reads: {exc}") from None
    try:
        return model_from_document(document)
    except CoreError as exc:
        raise fail(str(exc)) from None


def make_world(world: WorldName, world_seed: int, noise_std: float | None) -> World:
    """The simulated world named on the command line (:func:`core.evaluation.worlds.make_world`)."""
    from core.evaluation import make_world as make_named_world

    return make_named_world(world.value, world_seed=world_seed, noise_std=noise_std)


def simulate_dataset(
    world: Annotated[WorldName, typer.Argument(help="exp1 (the paper's) or exp2 (random, ds=2)")],
    out: Annotated[Path, typer.Option(help="CSV file to write.")],
    touches: Annotated[int, typer.Option(min=2, help="Touches per object.")] = 100,
    seed: Annotated[int, typer.Option(help="Seed of the actions and noise.")] = 0,
    world_seed: Annotated[int, typer.Option(help="Seed that draws the exp2 world.")] = 0,
    noise_std: Annotated[float | None, typer.Option(help="Observation noise std.")] = None,
) -> None:
    """Write a simulated training set (x ~ N(0, I) per touch) as a training CSV."""
    import numpy as np

    from app.documents.training_csv import write_training_csv
    from core.evaluation import sample_dataset

    data = sample_dataset(
        make_world(world, world_seed, noise_std), np.random.default_rng(seed), touches
    )
    write_text(out, write_training_csv(data), "--out")
    stderr.print(
        f"wrote {data.n_touches:d} touches of {data.n_objects:d} objects to {escape(str(out))}"
    )


@app.command()
def recognize(
    model_path: Annotated[Path, typer.Option("--model", help="Model document (JSON).")],
    target: Annotated[str, typer.Option(help="Name of the object being touched.")],
    world: Annotated[WorldName, typer.Option(help="World that produces the observations.")] = (
        WorldName.exp1
    ),
    policy: Annotated[
        Policy,
        typer.Option(
            help="active (information about the latent), discriminative (about which object), "
            "passive or fixed"
        ),
    ] = Policy.active,
    steps: Annotated[int, typer.Option(min=1, help="T, the largest number of touches.")] = 10,
    seed: Annotated[int, typer.Option(help="Seed of the noise and passive actions.")] = 0,
    action: Annotated[
        list[float] | None, typer.Option(help="The fixed action (repeat per dimension).")
    ] = None,
    tolerance: Annotated[float, typer.Option(help="Stop when the mean moves less.")] = 1e-3,
    confidence: Annotated[
        float | None, typer.Option(help="Stop when an object's probability reaches this.")
    ] = None,
    prior_variance: Annotated[
        float | None,
        typer.Option(
            help="Σ0 = this · I (normalised units; the paper's 5). Default: the objects' prior "
            "(their centre and spread, docs/method.md)."
        ),
    ] = None,
    world_seed: Annotated[int, typer.Option(help="Seed that drew the exp2 world.")] = 0,
    noise_std: Annotated[float | None, typer.Option(help="Observation noise std.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the trial as JSON.")] = False,
) -> None:
    """Run one simulated recognition trial, step by step."""
    import numpy as np

    from core.errors import CoreError
    from core.evaluation import PlannedTouches, WorldTouches, iter_trial
    from core.recognition import (
        Planner,
        RecognitionSession,
        RecognitionSettings,
        default_prior,
        make_policy,
    )

    model = load_model(model_path)
    if target not in model.object_names:
        raise fail(f"--target {target!r} is not an object of the model {list(model.object_names)}")
    try:
        chosen = make_policy(policy.value, np.asarray(action, dtype=np.float64) if action else None)
        planner = Planner(model, chosen)
        settings = RecognitionSettings(
            max_steps=steps, tolerance=tolerance, confidence_threshold=confidence
        )
        prior = default_prior(model, prior_variance)
        touches = WorldTouches(make_world(world, world_seed, noise_std), target)
        session = RecognitionSession(model, planner, prior, settings)
        rng = np.random.default_rng(seed)  # one stream for the planner and the noise
        records = []
        names = model.object_names
        for step, _ in iter_trial(session, PlannedTouches(touches), rng, rng):
            record = {
                "step": step.step,
                "action": step.action.tolist(),
                "observation": step.observation.tolist(),
                "mutual_information": step.mutual_information,
                "belief": {"mean": step.belief.mean.tolist(), "cov": step.belief.cov.tolist()},
                "nearest_object": names[step.nearest_object],
                "answer": names[step.answer],
                "probabilities": dict(zip(names, step.probabilities.tolist(), strict=True)),
                "done": step.done,
                "stop_reason": step.stop_reason,
            }
            records.append(record)
            if not as_json:
                shown_action = np.array2string(step.action, precision=3)
                shown_mean = np.array2string(step.belief.mean, precision=3)
                stdout.print(
                    f"step {step.step:2d}  x = {escape(shown_action)}  "
                    f"MI {step.mutual_information:.3f}  "
                    f"μ = {escape(shown_mean)}  "
                    f"nearest {escape(names[step.nearest_object])}  "
                    f"answer {escape(names[step.answer])} "
                    f"(p = {step.probabilities.max():.3f})"
                    + (f"  (stopped: {escape(step.stop_reason or '')})" if step.done else "")
                )
    except CoreError as exc:
        raise fail(str(exc)) from None
    final = records[-1]
    result = {
        "target": target,
        "policy": policy.value,
        "answer": final["answer"],
        "correct": final["answer"] == target,
        "steps": records,
    }
    if as_json:
        sys.stdout.write(json.dumps(result) + "\n")
    else:
        stdout.print(
            f"recognised {escape(final['answer'])} after {len(records):d} touches: "
            f"{'[green]correct[/green]' if result['correct'] else '[red]wrong[/red]'}"
        )


# Sub-commands that live with the code they drive (modules that import only typer and rich).
app.add_typer(rig_app, name="rig", help="Check and drive the rig (real ports or --sim).")
app.command("collect")(collect_command)
app.command("evaluate")(evaluate_command)
app.add_typer(export_app, name="export")
dataset_app.command("simulate")(simulate_dataset)
app.add_typer(dataset_app, name="dataset")
app.add_typer(paper_app, name="paper")

#: Context of a command that hands every argument (``--help`` included) to another command.
_FORWARDED: dict[str, Any] = {"allow_extra_args": True, "ignore_unknown_options": True}


def _forward(ctx: typer.Context, command: Callable[..., Any]) -> None:
    """Run the typer command function ``command`` on the arguments ``ctx`` received.

    ``command`` is parsed, checked and helped (``--help``) exactly as if it were registered
    here; it exits with its own code.
    """
    single = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    single.command()(command)
    single(args=list(ctx.args), prog_name=ctx.command_path)


def _forwarding_command(name: str, target: str, help_text: str) -> None:
    """Register ``name``: a thin command that imports ``target`` (``module:function``, a typer
    command function) only when it runs and forwards every argument to it (its help is the one
    shown)."""
    module, function = target.split(":")

    def forward(ctx: typer.Context) -> None:
        _forward(ctx, getattr(importlib.import_module(module), function))

    forward.__name__ = name
    forward.__doc__ = f"Forward to :func:`{module}.{function}`."
    app.command(name, help=help_text, context_settings=_FORWARDED, add_help_option=False)(forward)


_forwarding_command(
    "serve",
    "app.cli.serve:serve_command",
    "Run the REST API, the live event stream, the dashboard and the live 3D view.",
)
_forwarding_command(
    "demo",
    "app.cli.demo:demo_command",
    "Start everything on the simulated rig: dashboard, 3D view, a trained model.",
)
_forwarding_command(
    "bench",
    "app.cli.bench:bench_command",
    "Benchmark the likelihood, the fit, the mutual information, planning and scaling "
    "against GPy and the direct formulas (medians of repeats, BLAS threads pinned).",
)


#: The thread-count variables BLAS and OpenMP libraries read when they load.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def pin_blas_threads(environ: dict[str, str] | os._Environ[str] = os.environ) -> int:
    """Set the BLAS thread count for this process before numpy loads; return it.

    ``ACTIVETOUCH_BLAS_THREADS`` (a positive integer) sets every variable of
    :data:`BLAS_THREAD_VARIABLES`; without it each one already set is kept and the others
    become 1. It must run before the first import of numpy: a BLAS library reads them once, when
    it loads, and the commands import their stack lazily (a limit applied to the loaded
    libraries at start-up, as before, found none and left fits on two spinning threads:
    ``activetouch fit`` of Experiment 1 took 12.8 s instead of 5.2 s).

    Raises:
        typer.BadParameter: ``ACTIVETOUCH_BLAS_THREADS`` is not a positive integer.
    """
    asked = environ.get("ACTIVETOUCH_BLAS_THREADS")
    if asked is not None and not (asked.strip().isdigit() and int(asked) >= 1):
        raise typer.BadParameter(
            f"ACTIVETOUCH_BLAS_THREADS must be a positive integer, received {asked!r}."
        )
    for name in BLAS_THREAD_VARIABLES:
        if asked is not None:
            environ[name] = asked.strip()
        else:
            environ.setdefault(name, "1")
    try:
        return max(int(environ["OPENBLAS_NUM_THREADS"]), 1)
    except ValueError:  # a value of the user's own that OpenBLAS will judge itself
        return 1


def main() -> None:
    """Console-script entry point.

    BLAS runs on one thread unless ``ACTIVETOUCH_BLAS_THREADS`` (or a BLAS variable already set)
    says otherwise: the matrices of a few hundred touches are too small to gain from threads,
    and threads that spin on a busy machine slow every fit and plan several-fold.
    """
    try:
        threads = pin_blas_threads()
    except typer.BadParameter as exc:
        typer.echo(f"activetouch: {exc}", err=True)
        sys.exit(2)
    from threadpoolctl import threadpool_limits

    # Also for BLAS libraries already loaded (main() called from Python after numpy).
    with threadpool_limits(limits=threads):
        app()
