"""Rescore an evaluation's passive rig trials with the simulator's own placement covariance
(docs/calibration.md, "What a placement covariance could achieve, and a press-depth input").

A placement moves the object's contact angle by θ_p ~ N(0, σ_p²) and every lift-off adds a slip
of σ_s (``hardware.sim.noise.NoiseModel``: ``placement_std_deg``, ``slip_std_deg``). Linearised,
touch t of a trial then moves by g_l(x_t) θ_t, with g_l(x) = ∂y/∂θ of object l at action x, and
the trial's touches covary by

    g_l(x_t) g_l(x_u)ᵀ (σ_p² + σ_s² min(t, u)),   t, u = 0, 1, …,

between every pair of touches and features. g_l is measured here on a noise-free rig by central
differences in the contact angle, for every trial and every object hypothesis, and the covariance
is added to the model's trial covariance (eq. (C3)). It is an oracle, not a model: it says what
scoring the placement right would give, and which shape of covariance a fix must describe. The
trials' observations come from ``bench.placement_latent``'s cache (touched again when missing).

    python -m bench.placement_oracle --model M.json --report R.json --table cushions
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import scipy.linalg

from app.cli.main import load_model
from app.evaluation.cluster import local_cluster
from app.evaluation.context import rig_table
from bench.placement_latent import load_rescoring, rescoring_parser, score, summarise
from bench.sim_tables import QUIET
from core.gp.input_shift import shift_covariance
from core.gp.linalg import gaussian_log_density
from core.gp.placement_effect import predictive_covariance
from core.gp.posterior import predict_model_space
from core.recognition.object_posterior import object_log_likelihoods, shared_variance
from core.types import ManifoldModel
from core.validation import FloatArray

#: The simulator's defaults (``NoiseModel.placement_std_deg``, ``slip_std_deg``), degrees.
PLACEMENT_STD_DEG = 0.25
SLIP_STD_DEG = 0.1


def angle_responses(
    model_path: str, table: str, name: str, actions: list[list[float]], offset_deg: float
) -> list[list[float]]:
    """Observations of ``actions`` on object ``name`` with its contact angle moved by
    ``offset_deg``, on a rig with every noise term zero (deterministic)."""
    from app.evaluation.rig_trial import RigTrial
    from app.rig.actions import TouchActions

    base = next(item for item in rig_table(table).slots if item.name == name)
    moved = dataclasses.replace(base, contact_angle_deg=base.contact_angle_deg + offset_deg)
    model = load_model(Path(model_path))
    rig = RigTrial(
        TouchActions.from_teaching(), (moved,), name, 1, noise=QUIET, features=model.features
    )
    try:
        rng = np.random.default_rng(0)  # unused by the rig
        return [
            rig.touch(np.asarray(a, dtype=np.float64), rng).observation.tolist() for a in actions
        ]
    finally:
        rig.close()


def placement_covariance(slopes: FloatArray, placement_std: float, slip_std: float) -> FloatArray:
    """g(x_t) g(x_u)ᵀ (σ_p² + σ_s² min(t, u)) over a trial's touches and features, ordered
    feature-major (index a · T + t, as the trial covariance of
    :func:`core.gp.placement_effect.trial_log_likelihoods`).

    Args:
        slopes: g at the trial's touches, model space per degree. Shape (T, dy).
        placement_std: σ_p, degrees.
        slip_std: σ_s, degrees per lift-off.

    Returns:
        Shape (dy · T, dy · T).
    """
    t, dy = slopes.shape
    index = np.arange(t)
    angle = placement_std**2 + slip_std**2 * np.minimum.outer(index, index)
    flat = slopes.T.reshape(-1)
    return np.asarray(np.outer(flat, flat) * np.tile(angle, (dy, dy)), dtype=np.float64)


def oracle_log_likelihoods(
    model: ManifoldModel,
    actions: FloatArray,
    observations_raw: FloatArray,
    slopes: list[FloatArray],
    keep_shift: bool,
) -> FloatArray:
    """log p(y_1..y_T | l) with the placement covariance of object l added to the model's
    trial covariance (its σ_b², drift and, with ``keep_shift``, its input shift). ``slopes``:
    g_l for every object, model space. Shape (L,)."""
    h = model.hyperparameters
    t = actions.shape[0]
    residual_space = model.to_model_space(observations_raw)
    shared = shared_variance(model)
    within = h.noise_variance - shared
    jacobian = 0.0 if model.transform is None else model.transform.log_jacobian
    out = np.empty(model.latents.shape[0])
    for obj, latent in enumerate(model.latents):
        mean, _ = predict_model_space(model, np.tile(latent, (t, 1)), actions)
        cov_f = predictive_covariance(model, latent, actions)
        cov = scipy.linalg.block_diag(
            *[cov_f[a] + shared[a] + within[a] * np.eye(t) for a in range(h.observation_dim)]
        )
        if keep_shift and model.shift_variance is not None:
            cov = cov + shift_covariance(model, latent, actions, model.shift_variance, True)
        cov = cov + placement_covariance(slopes[obj][:t], PLACEMENT_STD_DEG, SLIP_STD_DEG)
        residual = (residual_space - mean).T.reshape(-1)
        out[obj] = gaussian_log_density(residual, cov, "trial covariance") + t * jacobian
    return out


def measure_slopes(
    args: argparse.Namespace, trials: list[dict[str, Any]], names: list[str]
) -> dict[str, list[list[list[float]]]]:
    """Raw responses at ± the step for every trial and object, cached next to the report."""
    cache = Path(args.report).with_suffix(f".angle-{args.step_deg}.json")
    if cache.exists():
        cached: dict[str, list[list[list[float]]]] = json.loads(cache.read_text())
        return cached
    from distributed import Client

    jobs = [(i, name, sign) for i in range(len(trials)) for name in names for sign in (1, -1)]
    with local_cluster(args.workers) as cluster, Client(cluster) as client:
        futures = client.map(
            angle_responses,
            [args.model] * len(jobs),
            [args.table] * len(jobs),
            [name for _, name, _ in jobs],
            [trials[i]["actions"] for i, _, _ in jobs],
            [sign * args.step_deg for _, _, sign in jobs],
            pure=False,
        )
        result = client.gather(futures)
    out: dict[str, list[list[list[float]]]] = {}
    for (i, name, _), response in zip(jobs, result, strict=True):
        out.setdefault(f"{i}/{name}", []).append(response)
    cache.write_text(json.dumps(out))
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the rescoring; returns what it printed, as data."""
    parser = rescoring_parser(__doc__.splitlines()[0])
    parser.add_argument("--step-deg", type=float, default=0.25)
    args = parser.parse_args(argv)
    run = load_rescoring(args)
    model, trials, observed, labels = run.model, run.trials, run.observed, run.labels
    steps, threshold = run.steps, run.threshold
    names = list(model.object_names)
    started = time.perf_counter()
    responses = measure_slopes(args, trials, names)
    print(f"slopes of {len(trials)} trials in {time.perf_counter() - started:.1f} s")
    slopes = [
        [
            (
                model.to_model_space(np.asarray(responses[f"{i}/{name}"][0]))
                - model.to_model_space(np.asarray(responses[f"{i}/{name}"][1]))
            )
            / (2 * args.step_deg)
            for name in names
        ]
        for i in range(len(trials))
    ]
    results: dict[str, Any] = {}
    as_is = score(
        trials, observed, lambda x, y: object_log_likelihoods(model, x, y), len(names), steps
    )
    results["as_it_is"] = summarise("as it is", as_is, labels, steps, threshold)
    for label, keep_shift in (("+ placement", True), ("placement for shift", False)):
        probabilities = np.stack(
            [
                score(
                    [trial],
                    [y],
                    lambda x, z, g=g, k=keep_shift: oracle_log_likelihoods(model, x, z, g, k),
                    len(names),
                    steps,
                )[0]
                for trial, y, g in zip(trials, observed, slopes, strict=True)
            ]
        )
        results[label] = summarise(label, probabilities, labels, steps, threshold)
    return results


if __name__ == "__main__":
    main()
