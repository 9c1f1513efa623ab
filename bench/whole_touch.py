"""Benchmark: recognition from the whole touch against channel means, and the fit's time.

Two parts:

1. **Twins** (``--part twins``): the simulated ``twins`` table (four objects of one material
   whose every channel has the same mean; they differ in the vibration's spectrum and the spread
   of the electrode ring, ``hardware/sim/electrodes.py``), ``--touches`` touches per object on
   the in-process simulated rig (random design, x ~ N(0, σ² I) with the table's σ, rounds over
   the objects as ``activetouch collect`` does, touches of ``--duration`` s, by default the
   duration rig trials touch for) — or the raw-touch file ``--data`` (what ``activetouch
   collect --sim --table twins --raw FILE`` writes). The first ``--fit`` touches of each object
   train, the rest are held out. For each feature pipeline (``means``: each channel's mean;
   ``whole``: reducers, standardisation, PCA/LDA with dy by cross-validation) a manifold is
   fitted (ds = ``--latent-dim``, noise model auto, 2 restarts) with the pipeline in the model,
   and evaluated by the evaluation engine (:func:`app.evaluation.runner.run_evaluation`),
   policies active and passive, 3 touches per trial: replaying the held-out touches
   (``--trials`` trials per object) and on the simulated rig (``--rig-trials`` per object, every
   touch a fresh simulated touch through the model's pipeline). Each accuracy comes with its
   calibration: the ECE and "sure and wrong" (answers given with p ≥ 0.95 that were wrong) after
   touch 1 and touch 3, and the reliability table over every touch.
2. **Fit time** (``--part fit``): 20 objects × ``--fit-touches`` (40) synthetic whole touches
   shaped like a multimodal fingertip's (19 electrodes and pressure/thermal channels at 100 Hz,
   a vibration at 2.2 kHz); the time to fit the feature pipeline (dy chosen by
   cross-validation), then the manifold at ``--fit-dims`` features (ds = 3, noise model
   independent, 2 restarts) with each of ``--kernels`` (``tied`` by default: the features share
   their length-scales, docs/fitting.md "Tied kernels"; ``per_feature`` is today's model, slow
   from dy = 10 on): wall and CPU seconds, likelihood evaluations (on all the data, with
   gradient and value alone, and on smaller problems) and the log-likelihood. ``--held-out K``
   touches per object more are drawn and held out: each model's mean held-out predictive
   log-density per touch and one-touch recognition. ``--eval-dims`` times one evaluation with
   gradient on all the data per dy, per-feature and tied (where they cross over).

Run: ``.venv/bin/python -m bench.whole_touch [--part twins|fit|both] [--data FILE.jsonl]
[--features means whole] [--touches 100] [--fit 80] [--trials 50] [--rig-trials 10]
[--workers 2] [--fit-dims 10 20 30] [--kernels tied per_feature] [--fit-touches 40]
[--held-out 0] [--eval-dims 1 5 10] [--json]``.
The figures measured are in docs/results.md ("Whole touch against channel means").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import scipy.special
from threadpoolctl import threadpool_limits

from app.documents.raw_touches import raw_touch_from_record, read_raw_touches
from app.evaluation.runner import run_evaluation
from app.evaluation.spec import EvaluationSpec
from app.rig.actions import TouchActions
from app.rig.build import SimulationMode, open_rig
from app.services.collections import iter_collection
from bench.fit_n800 import _COUNTS, instrument
from core.evaluation import random_design
from core.features.pipeline import FeatureKind, fit_features
from core.features.raw import RawTouch, raw_touch
from core.gp import KERNELS, FitOptions, fit_manifold, make_likelihood
from core.gp.parameters import initial_hyperparameters
from core.recognition import object_log_likelihoods, touch_log_likelihoods
from core.types import ManifoldModel, TrainingData
from core.validation import FloatArray, IntArray
from hardware.rig import RigConfig
from hardware.sim.materials import get_table
from hardware.teaching import PAPER_TOUCH_DURATION_S


def collect_twins(
    touches: int, duration_s: float, seed: int
) -> tuple[tuple[str, ...], IntArray, FloatArray, list[RawTouch]]:
    """Touch every object of the twins table ``touches`` times; the raw touches, in order."""
    table = get_table("twins")
    handle = open_rig(simulate=SimulationMode.in_process, table="twins", seed=seed)
    actions = TouchActions.from_teaching(dt_s=RigConfig().control_period_s, duration_s=duration_s)
    rng = np.random.default_rng(seed)
    dx = actions.action_dim
    plan = random_design(
        len(table.objects), touches, np.zeros(dx), table.action_std**2 * np.eye(dx), rng
    )
    slots = {name: slot for slot, name in enumerate(table.objects)}
    index, xs, raws = [], [], []
    try:
        with handle.rig.acquire("bench whole_touch") as lease:
            lease.connect()
            for touch in iter_collection(lease, actions, slots, plan):
                index.append(table.objects.index(touch.object_name))
                xs.append(touch.action)
                raws.append(raw_touch_from_record(touch.record))
    finally:
        handle.close()
    return table.objects, np.asarray(index), np.asarray(xs), raws


def split(index: IntArray, first: int) -> tuple[IntArray, IntArray]:
    """Rows of the first ``first`` touches of each object, and of the rest."""
    fit_rows, held_rows = [], []
    for obj in np.unique(index):
        rows = np.flatnonzero(index == obj)
        fit_rows += list(rows[:first])
        held_rows += list(rows[first:])
    return np.asarray(sorted(fit_rows)), np.asarray(sorted(held_rows))


def touch_summary(entry: dict[str, Any], touch: int) -> dict[str, Any]:
    """Accuracy after ``touch`` touches with its 95 % interval and calibration (ECE, Brier,
    "sure and wrong") from one policy's evaluation summary."""
    calibration = entry["calibration"]["by_touch"][touch - 1]
    return {
        "accuracy": entry["accuracy_by_touch"][touch - 1],
        "interval": entry["accuracy_interval"][touch - 1],
        "ece": calibration["ece"],
        "brier": calibration["brier"],
        "sure_and_wrong": calibration["sure_and_wrong"],
    }


def evaluate(
    model: ManifoldModel, spec: EvaluationSpec, replay: TrainingData | None, workers: int | None
) -> dict[str, Any]:
    """Run one evaluation; per policy: after touch 1 and 3, the reliability over every touch."""
    started = time.perf_counter()
    report = run_evaluation(model, spec, replay=replay, workers=workers)
    figures: dict[str, Any] = {"seconds": time.perf_counter() - started}
    for policy, entry in report.summary().items():
        figures[policy] = {
            "trials": entry["trials"],
            "after_1": touch_summary(entry, 1),
            "after_3": touch_summary(entry, min(3, spec.steps)),
            "reliability": entry["calibration"]["all_touches"]["reliability"],
        }
    figures["refused"] = report.refused_by_policy()
    after = {p: (figures[p]["after_1"], figures[p]["after_3"]) for p in report.summary()}
    print(json.dumps({spec.world: after}), file=sys.stderr, flush=True)
    return figures


def twins_touches(
    args: argparse.Namespace,
) -> tuple[tuple[str, ...], IntArray, FloatArray, list[RawTouch]]:
    """The twins touches: read from ``--data``, or collected on the simulated rig."""
    if args.data is None:
        return collect_twins(args.touches, args.duration, args.seed)
    touches = read_raw_touches(Path(args.data).read_text(encoding="utf-8"))
    return touches.object_names, touches.object_index, touches.actions, list(touches.touches)


def run_twins(args: argparse.Namespace) -> dict[str, Any]:
    """Part 1: means vs whole touch on the twins table, replayed and on the rig."""
    started = time.perf_counter()
    names, index, actions, raws = twins_touches(args)
    collect_s = time.perf_counter() - started
    fit_rows, held_rows = split(index, args.fit)
    figures: dict[str, Any] = {
        "objects": list(names),
        "touches": len(raws),
        "fit_per_object": args.fit,
        "data": args.data,
        "collect_s": None if args.data else collect_s,
    }
    kinds: tuple[FeatureKind, ...] = tuple(args.features)
    policies = ("active", "passive")
    for kind in kinds:
        started = time.perf_counter()
        pipeline = fit_features([raws[i] for i in fit_rows], index[fit_rows], kind, seed=args.seed)
        features_s = time.perf_counter() - started
        y = pipeline.transform_many(raws)
        data = TrainingData(names, index[fit_rows], actions[fit_rows], y[fit_rows])
        started = time.perf_counter()
        model = fit_manifold(
            data,
            args.latent_dim,
            np.random.default_rng(args.seed),
            FitOptions(restarts=2),
            noise_model="auto",
        )
        fit_s = time.perf_counter() - started
        model = dataclasses.replace(model, features=pipeline)
        print(f"{kind}: dy = {pipeline.output_dim}, fit {fit_s:.0f} s", file=sys.stderr, flush=True)
        held = TrainingData(names, index[held_rows], actions[held_rows], y[held_rows])
        replay = EvaluationSpec("replay", args.trials, 3, policies, seed=args.seed)
        rig = EvaluationSpec("rig", args.rig_trials, 3, policies, seed=args.seed, table="twins")
        figures[kind] = {
            "dy": pipeline.output_dim,
            "projection": pipeline.projection if kind == "whole" else None,
            "selection": None if pipeline.selection is None else pipeline.selection.explanation,
            "features_s": features_s,
            "fit_s": fit_s,
            "noise_model": None if model.transform is None else model.transform.note,
            "replay": evaluate(model, replay, held, args.workers),
            "rig": evaluate(model, rig, None, args.workers) if args.rig_trials > 0 else None,
        }
    return figures


def synthetic_fingertip(
    n_objects: int, touches: int, seed: int
) -> tuple[IntArray, FloatArray, list[RawTouch]]:
    """Whole touches shaped like a multimodal fingertip's: 19 electrodes, pressure, heat flux
    and temperature at 100 Hz over 1.5 s, a vibration at 2.2 kHz; each object has its own
    electrode pattern, texture frequency and thermal response, the action its sliding speed."""
    rng = np.random.default_rng(seed)
    patterns = rng.uniform(0.5, 1.5, size=(n_objects, 19))
    textures_hz = rng.uniform(40.0, 400.0, size=n_objects)
    thermal = rng.uniform(0.5, 2.0, size=n_objects)
    t_slow = np.arange(150) / 100.0
    t_fast = np.arange(3300) / 2200.0
    index, xs, raws = [], [], []
    for _ in range(touches):
        for obj in range(n_objects):
            x = rng.normal(size=2)
            speed = 1.0 + 0.2 * np.tanh(x[0])
            force = 1.0 + 0.2 * np.tanh(x[1])
            envelope = force * np.sin(np.pi * t_slow / t_slow[-1]) ** 0.5
            raws.append(
                raw_touch(
                    {
                        "electrodes": (
                            100.0,
                            envelope[:, None] * patterns[obj] + 0.05 * rng.normal(size=(150, 19)),
                        ),
                        "pressure": (100.0, envelope + 0.02 * rng.normal(size=150)),
                        "heat_flux": (
                            100.0,
                            thermal[obj] * np.exp(-t_slow) + 0.05 * rng.normal(size=150),
                        ),
                        "temperature": (
                            100.0,
                            33.0 - 0.3 * thermal[obj] * t_slow + 0.02 * rng.normal(size=150),
                        ),
                        "vibration": (
                            2200.0,
                            force
                            * np.sin(
                                2 * np.pi * textures_hz[obj] * speed * t_fast + rng.uniform(0, 7)
                            )
                            + 0.3 * rng.normal(size=3300),
                        ),
                    }
                )
            )
            index.append(obj)
            xs.append(x)
    return np.asarray(index), np.asarray(xs), raws


def time_evaluations(data: TrainingData, kernels: str, repeats: int, latent_dim: int = 3) -> float:
    """Median seconds of one evaluation with gradient on all of ``data`` (initial
    hyperparameters, random latents) with ``kernels``."""
    likelihood = make_likelihood(data, latent_dim, "dense", kernels=kernels)  # type: ignore[arg-type]
    rng = np.random.default_rng(0)
    vector = likelihood.layout.pack(
        rng.standard_normal((data.n_objects, latent_dim)),
        initial_hyperparameters(data, latent_dim),
    )
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        likelihood.value_and_gradient(vector)
        seconds.append(time.perf_counter() - started)
    return float(np.median(seconds))


def evaluation_counts(data: TrainingData) -> dict[str, int]:
    """Evaluations counted since the last reset: with gradient and value alone, on all the
    data and on smaller problems (screening subsample; one-feature hyperparameter stages)."""
    out = {"all_data_gradient": 0, "all_data_value": 0, "smaller_problems": 0}
    for (size, features, kind), (evaluations, _) in _COUNTS.items():
        if (size, features) == (data.n_touches, data.observation_dim):
            out["all_data_gradient" if kind == "grad" else "all_data_value"] += int(evaluations)
        else:
            out["smaller_problems"] += int(evaluations)
    return out


def held_out_scores(
    model: ManifoldModel, index: IntArray, actions: FloatArray, observations: FloatArray
) -> dict[str, float]:
    """Mean held-out predictive log-density per touch under its own object; from each held-out
    touch alone (uniform prior over the objects): the share recognised (most likely object)
    and the mean log-loss, -log P(true object | touch)."""
    density = touch_log_likelihoods(model, index, actions, observations)
    right, losses = [], []
    for t in range(index.size):
        scores = object_log_likelihoods(model, actions[t : t + 1], observations[t : t + 1])
        right.append(int(np.argmax(scores)) == int(index[t]))
        losses.append(float(scipy.special.logsumexp(scores) - scores[index[t]]))
    return {
        "held_out_log_density_per_touch": float(np.mean(density)),
        "one_touch_accuracy": float(np.mean(right)),
        "one_touch_log_loss": float(np.mean(losses)),
    }


def run_fit(args: argparse.Namespace) -> dict[str, Any]:
    """Part 2: time of the pipeline and of the manifold fit at several dy and kernels."""
    n_objects, touches = 20, args.fit_touches
    index, actions, raws = synthetic_fingertip(n_objects, touches + args.held_out, args.seed)
    # synthetic_fingertip goes round the objects: the first ``touches`` rounds train.
    train = np.arange(index.size) < n_objects * touches
    train_raws = [r for r, keep in zip(raws, train, strict=True) if keep]
    test_raws = [r for r, keep in zip(raws, train, strict=True) if not keep]
    names = tuple(f"material_{k:02d}" for k in range(n_objects))
    started = time.perf_counter()
    chosen = fit_features(train_raws, index[train], "whole", seed=args.seed)
    print(f"pipeline fitted in {time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)
    figures: dict[str, Any] = {
        "touches": len(train_raws),
        "held_out_touches": len(test_raws),
        "reduced_features": len(chosen.reduced_names),
        "pipeline_s": time.perf_counter() - started,
        "selection": chosen.selection.explanation if chosen.selection else None,
        "evaluation_s": [],
        "fits": [],
    }
    instrument()
    dims = sorted(set(args.fit_dims) | set(args.eval_dims))
    for dy in dims:
        pipeline = fit_features(train_raws, index[train], "whole", feature_dim=dy, projection="pca")
        observations = pipeline.transform_many(train_raws)
        data = TrainingData(names, index[train], actions[train], observations)
        if dy in args.eval_dims:
            for kernels in KERNELS:
                seconds = time_evaluations(data, kernels, 3)
                entry = {"dy": dy, "kernels": kernels, "seconds": seconds}
                figures["evaluation_s"].append(entry)
                print(json.dumps(entry), file=sys.stderr, flush=True)
        if dy not in args.fit_dims:
            continue
        for kernels in args.kernels:
            _COUNTS.clear()
            started, cpu_started = time.perf_counter(), time.process_time()
            model = fit_manifold(
                data,
                3,
                np.random.default_rng(args.seed),
                FitOptions(restarts=2, kernels=kernels),
                noise_model="independent",
            )
            entry = {
                "dy": dy,
                "kernels": kernels,
                "fit_s": time.perf_counter() - started,
                "cpu_s": time.process_time() - cpu_started,
                "evaluations": evaluation_counts(data),
                "log_likelihood": model.log_likelihood,
            }
            if test_raws:
                observations = pipeline.transform_many(test_raws)
                entry.update(held_out_scores(model, index[~train], actions[~train], observations))
            figures["fits"].append(entry)
            print(json.dumps(entry), file=sys.stderr, flush=True)
    return figures


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; print and return the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("twins", "fit", "both"), default="both")
    parser.add_argument("--touches", type=int, default=100, help="Touches per object.")
    parser.add_argument("--fit", type=int, default=80, help="Touches per object used to fit.")
    parser.add_argument(
        "--duration",
        type=float,
        default=PAPER_TOUCH_DURATION_S,
        help="Touch duration (s) of the collection (rig trials touch for the default).",
    )
    parser.add_argument("--data", help="A twins raw-touch file instead of collecting.")
    parser.add_argument(
        "--features",
        nargs="+",
        choices=("means", "whole"),
        default=["means", "whole"],
        help="Feature pipelines of the twins part.",
    )
    parser.add_argument("--latent-dim", type=int, default=2, help="ds of the twins models.")
    parser.add_argument("--trials", type=int, default=50, help="Replay trials per object.")
    parser.add_argument("--rig-trials", type=int, default=10, help="Rig trials per object.")
    parser.add_argument("--workers", type=int, default=None, help="Dask workers of the trials.")
    parser.add_argument(
        "--fit-dims", type=int, nargs="*", default=[10, 20, 30], help="dy of the timed fits."
    )
    parser.add_argument(
        "--kernels",
        nargs="+",
        choices=("per_feature", "tied"),
        default=["tied"],
        help="Kernels of the timed fits (per_feature is slow from dy = 10 on).",
    )
    parser.add_argument(
        "--fit-touches", type=int, default=40, help="Training touches per object of the fit part."
    )
    parser.add_argument(
        "--held-out",
        type=int,
        default=0,
        help="Touches per object held out of the fit part: held-out log-density and one-touch "
        "recognition of every fitted model.",
    )
    parser.add_argument(
        "--eval-dims",
        type=int,
        nargs="*",
        default=[],
        help="dy at which one evaluation with gradient is timed, per-feature and tied.",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="Print the figures as JSON only.")
    args = parser.parse_args(argv)
    figures: dict[str, Any] = {"benchmark": "whole_touch"}
    with threadpool_limits(limits=1):
        if args.part in ("twins", "both"):
            figures["twins"] = run_twins(args)
        if args.part in ("fit", "both"):
            figures["fit"] = run_fit(args)
    sys.stdout.write(json.dumps(figures, indent=None if args.json else 1) + "\n")
    return figures


if __name__ == "__main__":
    main()
