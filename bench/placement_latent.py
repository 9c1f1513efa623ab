"""Rescore an evaluation's rig trials with a latent per placement (docs/calibration.md, "A latent
per placement, measured").

Each trial of an ``activetouch evaluate --world rig`` report is touched again on its own simulated
rig (the recorded actions, the trial's seed: the same observations), then scored after every
touch twice: by the model as it is (which gives back the recorded answers) and by the model
refitted with a latent per placement (:mod:`core.gp.placement_latent`), a new trial being a new
placement whose u is integrated over. Only passive trials rescore exactly: the planners' actions
depend on the answers. Prints accuracy by touch, ECE, log-loss and the sure answers that were
wrong, for both.

    python -m bench.placement_latent --model M.json --report R.json --table cushions
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.cli.main import load_model
from app.evaluation.cluster import local_cluster
from app.evaluation.context import rig_table
from app.evaluation.rig_trial import RigTrial, rig_seed
from core.evaluation.calibration import calibration
from core.gp.likelihood import ManifoldLikelihood
from core.gp.placement_latent_fit import fit_placement_latents
from core.recognition.object_posterior import normalise_log_probabilities, object_log_likelihoods
from core.recognition.placement_latent import placement_latent_model, trial_log_likelihoods
from core.types import ManifoldModel


def touch_again(model_path: str, table: str, trial: dict[str, Any]) -> list[list[float]]:
    """The observations of one recorded rig trial, touched again on its own rig."""
    from app.rig.actions import TouchActions

    model = load_model(Path(model_path))
    rig = RigTrial(
        TouchActions.from_teaching(),
        rig_table(table).slots,
        trial["target"],
        rig_seed(tuple(trial["seed"])),
        features=model.features,
    )
    try:
        rng = np.random.default_rng(0)  # unused by the rig
        return [
            rig.touch(np.asarray(a, dtype=np.float64), rng).observation.tolist()
            for a in trial["actions"]
        ]
    finally:
        rig.close()


def observations(args: argparse.Namespace, trials: list[dict[str, Any]]) -> list[np.ndarray]:
    """Every trial's observations, from the cache next to the report or touched again."""
    cache = Path(args.report).with_suffix(".observations.json")
    if cache.exists():
        return [np.asarray(o) for o in json.loads(cache.read_text())]
    from distributed import Client

    with local_cluster(args.workers) as cluster, Client(cluster) as client:
        futures = client.map(
            touch_again, [args.model] * len(trials), [args.table] * len(trials), trials
        )
        result = client.gather(futures)
    cache.write_text(json.dumps(result))
    return [np.asarray(o) for o in result]


def summarise(
    name: str, probabilities: np.ndarray, labels: np.ndarray, steps: int, threshold: float
) -> dict[str, Any]:
    """Accuracy by touch, and the calibration over every trial and touch.

    ``probabilities`` (trials, steps, L); ``labels`` (trials,)."""
    by_touch = [
        float(np.mean(np.argmax(probabilities[:, t], axis=1) == labels)) for t in range(steps)
    ]
    flat = probabilities.reshape(-1, probabilities.shape[2])
    every = calibration(flat, np.repeat(labels, steps), threshold)
    sure = every.sure_and_wrong
    print(
        f"  {name:<22} accuracy % {' '.join(f'{100 * a:.1f}' for a in by_touch)}  "
        f"ECE {every.ece:.3f}  log-loss {every.log_loss:.3f}  sure & wrong "
        f"{sure.wrong}/{sure.sure} ({100 * sure.wrong / max(sure.sure, 1):.1f} %)"
    )
    return {"accuracy_by_touch": by_touch, "calibration": every.to_dict()}


def score(
    trials: list[dict[str, Any]],
    observed: list[np.ndarray],
    scorer: Any,
    n_objects: int,
    steps: int,
) -> np.ndarray:
    """Posterior after every touch of every trial. Shape (trials, steps, L)."""
    out = np.empty((len(trials), steps, n_objects))
    for i, (trial, y) in enumerate(zip(trials, observed, strict=True)):
        x = np.asarray(trial["actions"], dtype=np.float64)
        for t in range(steps):
            out[i, t] = normalise_log_probabilities(scorer(x[: t + 1], y[: t + 1]))
    return out


def rescoring_parser(description: str) -> argparse.ArgumentParser:
    """The arguments every rescoring of a report's rig trials takes."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--model", required=True)
    parser.add_argument("--report", required=True)
    parser.add_argument("--table", required=True)
    parser.add_argument("--policy", default="passive")
    parser.add_argument("--workers", type=int, default=2)
    return parser


@dataclasses.dataclass(frozen=True)
class Rescoring:
    """A report's complete trials of one policy, with the model and what scoring them needs."""

    model: ManifoldModel
    trials: list[dict[str, Any]]
    observed: list[np.ndarray]
    labels: np.ndarray
    steps: int
    threshold: float


def load_rescoring(args: argparse.Namespace) -> Rescoring:
    """The model, the report's complete trials of ``args.policy`` and their observations."""
    model: ManifoldModel = load_model(Path(args.model))
    report = json.loads(Path(args.report).read_text())
    steps = int(report["steps"])
    trials = [
        t for t in report["trials"] if t["policy"] == args.policy and len(t["actions"]) == steps
    ]
    names = list(model.object_names)
    labels = np.array([names.index(t["target"]) for t in trials])
    started = time.perf_counter()
    observed = observations(args, trials)
    print(
        f"{len(trials)} {args.policy} trials' observations in {time.perf_counter() - started:.1f} s"
    )
    return Rescoring(model, trials, observed, labels, steps, float(report["confidence"]))


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the rescoring; returns what it printed, as data."""
    parser = rescoring_parser(__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--variants",
        default="free,floor,offset",
        help="free: σ_n² fitted freely; floor: σ_n² ≥ the model's σ_n² − σ_b²; offset: the "
        "model's σ_b² shared by a placement's touches beside u (in the fit and the score)",
    )
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    run = load_rescoring(args)
    model, trials, observed, labels = run.model, run.trials, run.observed, run.labels
    steps, threshold = run.steps, run.threshold
    names = list(model.object_names)
    results: dict[str, Any] = {}
    as_is = score(
        trials, observed, lambda x, y: object_log_likelihoods(model, x, y), len(names), steps
    )
    recorded = np.array([t["probabilities"] for t in trials])
    print(f"  rescoring as it is vs recorded: max |Δp| {np.max(np.abs(as_is - recorded)):.2e}")
    results["as_it_is"] = summarise("as it is", as_is, labels, steps, threshold)

    hyper = model.hyperparameters
    in_fit = model.placement_variance if model.placement_in_fit else None
    base = ManifoldLikelihood(model.data, model.latent_dim, placement_variance=in_fit)
    if in_fit is not None:  # the likelihood packs the within-placement noise
        hyper = dataclasses.replace(hyper, noise_variance=hyper.noise_variance - in_fit)
    base_value = base.value(base.layout.pack(model.latents, hyper))
    print(f"-log p of the model as it is, in its model space: {base_value:.2f}")
    variants: dict[str, dict[str, Any]] = {"free": {}}
    if model.placement_variance is not None:
        within = model.hyperparameters.noise_variance - model.placement_variance
        variants["floor"] = {"noise_floor": within}
        variants["offset"] = {"placement_variance": model.placement_variance}
    for label in args.variants.split(","):
        started = time.perf_counter()
        fit = fit_placement_latents(
            model.data,
            model.latents,
            model.hyperparameters,
            seed=args.seed,
            max_iterations=args.iterations,
            **variants[label],
        )
        fit_s = time.perf_counter() - started
        h = fit.hyperparameters
        print(
            f"placement latents ({label}): {fit.placements.n_placements} placements, "
            f"{fit.iterations} iterations in {fit_s:.1f} s ({fit.message}); -log p "
            f"{fit.negative_log_posterior:.2f}\n"
            f"  ℓ^u {np.round(h.latent_lengthscales[:, -1], 3).tolist()}, σ_n² "
            f"{np.round(h.noise_variance / model.hyperparameters.noise_variance, 3).tolist()} "
            "of before"
        )
        drift = model.drift_variance
        shared = None if drift is None else np.minimum(drift, 0.5 * h.noise_variance)
        placed = placement_latent_model(model, fit, shared_variance=shared)
        latent_scores = score(
            trials,
            observed,
            lambda x, y, m=placed: trial_log_likelihoods(m, x, y),
            len(names),
            steps,
        )
        results[label] = summarise(label, latent_scores, labels, steps, threshold)
        results[label]["fit"] = {
            "placements": fit.placements.n_placements,
            "iterations": fit.iterations,
            "seconds": fit_s,
            "negative_log_posterior": fit.negative_log_posterior,
            "offset_lengthscales": h.latent_lengthscales[:, -1].tolist(),
            "noise_variance": h.noise_variance.tolist(),
        }
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return results


if __name__ == "__main__":
    main()
